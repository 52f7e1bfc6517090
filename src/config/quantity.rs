//! Numbers as they read in messages and docs: compact plain numbers (`0.28`, `1e13`) and
//! quantities with an SI prefix (`6 MHz`, `500 µs`).

/// A number in its shortest exact form, in scientific notation when it is very large or
/// small, so that ranges read `0 < value ≤ 1e13` rather than `10000000000000`.
pub(crate) fn number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-3..1e5).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// A value with its unit and an SI prefix chosen so the mantissa lies in [1, 1000)
/// (`6e6`, `"Hz"` → `6 MHz`). Dimensionless (`"1"`) and unitless values are plain numbers.
pub(crate) fn quantity(x: f64, unit: &str) -> String {
    // Six decimals keep neighbouring values (a value and its limit) distinguishable;
    // trailing zeros carry no information.
    with_prefix(x, unit, |mantissa| format!("{mantissa:.6}"))
}

/// [`quantity`] rounded to `significant` digits (at least 1) for reports of computed values
/// (`6.5953e-8`, `"N"`, 4 → `65.95 nN`; `2e6`, `"Pa"`, 3 → `2 MPa`).
pub(crate) fn quantity_rounded(x: f64, unit: &str, significant: usize) -> String {
    let significant = significant.max(1) as i32;
    let rounded = if x == 0.0 || !x.is_finite() {
        x
    } else {
        // Rounded before the prefix is chosen, so 999.96 rounds to 1 k…, not 1000 ….
        // By a power of ten that is exact (10^k, k ≥ 0), so 0.0518 stays 0.0518.
        let k = significant - 1 - x.abs().log10().floor() as i32;
        if k >= 0 {
            let scale = 10f64.powi(k);
            (x * scale).round() / scale
        } else {
            let scale = 10f64.powi(-k);
            (x / scale).round() * scale
        }
    };
    if unit.is_empty() || unit == "1" {
        return number(rounded);
    }
    with_prefix(rounded, unit, |mantissa| {
        let integer_digits = mantissa.abs().log10().floor() as i32 + 1;
        let decimals = (significant - integer_digits).max(0) as usize;
        format!("{mantissa:.decimals$}")
    })
}

/// `x` as `digits(mantissa) prefix unit`, the mantissa in [1, 1000), trailing zeros dropped.
fn with_prefix(x: f64, unit: &str, digits: impl Fn(f64) -> String) -> String {
    if unit.is_empty() || unit == "1" {
        return number(x);
    }
    if x == 0.0 || !x.is_finite() {
        return format!("{} {unit}", number(x));
    }
    const PREFIXES: [(i32, &str); 10] = [
        (-15, "f"),
        (-12, "p"),
        (-9, "n"),
        (-6, "µ"),
        (-3, "m"),
        (0, ""),
        (3, "k"),
        (6, "M"),
        (9, "G"),
        (12, "T"),
    ];
    let exponent = ((x.abs().log10() / 3.0).floor() as i32 * 3).clamp(-15, 12);
    let prefix = PREFIXES
        .iter()
        .find(|(e, _)| *e == exponent)
        .map_or("", |(_, p)| *p);
    let mantissa = x / 10f64.powi(exponent);
    let digits = digits(mantissa);
    let digits = if digits.contains('.') {
        digits.trim_end_matches('0').trim_end_matches('.')
    } else {
        &digits
    };
    format!("{digits} {prefix}{unit}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_compact() {
        assert_eq!(number(0.28), "0.28");
        assert_eq!(number(-1.0), "-1");
        assert_eq!(number(100e3), "1e5");
        assert_eq!(number(1000.0), "1000");
        assert_eq!(number(1e13), "1e13");
        assert_eq!(number(5e-4), "5e-4");
        assert_eq!(number(129e9), "1.29e11");
        assert_eq!(number(0.0), "0");
    }

    #[test]
    fn quantities_take_si_prefixes() {
        assert_eq!(quantity(6e6, "Hz"), "6 MHz");
        assert_eq!(quantity(5e6, "Hz"), "5 MHz");
        assert_eq!(quantity(5e-4, "s"), "500 µs");
        assert_eq!(quantity(1e-7, "s"), "100 ns");
        assert_eq!(quantity(20.0, "N/m"), "20 N/m");
        assert_eq!(quantity(129e9, "Pa"), "129 GPa");
        assert_eq!(quantity(3.2e6, "Hz"), "3.2 MHz");
        assert_eq!(quantity(0.28, "1"), "0.28");
    }

    #[test]
    fn rounded_quantities_keep_the_significant_digits_asked_for() {
        assert_eq!(quantity_rounded(2e6, "Pa", 3), "2 MPa");
        assert_eq!(quantity_rounded(6.5953e-8, "N", 4), "65.95 nN");
        assert_eq!(quantity_rounded(-4.2e-10, "m", 3), "-420 pm");
        assert_eq!(quantity_rounded(999.96, "Hz", 4), "1 kHz");
        assert_eq!(quantity_rounded(100e3, "Hz", 6), "100 kHz");
        assert_eq!(quantity_rounded(1234.5, "N/m", 2), "1.2 kN/m");
        assert_eq!(quantity_rounded(0.0, "m", 3), "0 m");
        assert_eq!(quantity_rounded(0.051834, "1", 3), "0.0518");
    }
}
