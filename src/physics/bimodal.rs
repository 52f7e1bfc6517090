//! Bimodal AM-FM: the first mode under amplitude modulation (its amplitude A1 and phase
//! lag φ1 against a free amplitude A01), the second driven at a small amplitude whose
//! frequency shift Δf2 reads the contact's stiffness; together they give the tip's mean
//! force, the contact's mean stiffness, the indentation and the reduced modulus E*
//! (Herruzo, Perrino & Garcia, Nat. Commun. 5, 3126 (2014); Benaglia et al., Nat. Protoc.
//! 13, 2890 (2018)), derived here with this project's conventions:
//!
//! - The first mode's virial: at resonance its drive balances the force's component in
//!   phase with the swing, ⟨F·cos θ⟩ = k1·A01·cos φ1/(2Q1) (θ the swing's phase from its
//!   lowest point; φ1 = 90° free, below 90° in repulsive tapping). A tap short against the
//!   swing, at θ ≈ 0, makes it the mean force ⟨F⟩.
//! - The second mode, of small amplitude, feels the contact's stiffness averaged over the
//!   first's swing: Δf2/f2 = ⟨k_ts⟩/(2k2), so ⟨k_ts⟩ = 2k2·Δf2/f2.
//! - A Hertz contact F = (4/3)E*√R·δ^{3/2} at the bottom of a swing of amplitude A1 lasts
//!   while δ = d − A1·(1 − cos θ) > 0 (d the deepest indentation). For a short tap,
//!   δ ≈ d − A1·θ²/2, so over a period ⟨F⟩ = E*√R·d²/(2√(2A1)) and ⟨k_ts⟩ = E*√R·d/√(2A1).
//! - Hence the published expressions d = 2⟨F⟩/⟨k_ts⟩ and E* = ⟨k_ts⟩·√(2A1)/(√R·d)
//!   = 4√2·(k2·Δf2/f2)²·Q1·√A1/(√R·k1·A01·cos φ1).
//!
//! Those hold where the contact is short (d ≪ A1): at d/A1 = 0.1 they overstate E* by
//! 2.6 %, at 0.38 (a soft sample) by 11 %. [`estimate`] therefore also solves the same two
//! averages over the whole swing, without the parabola and the short tap: with x = d/A1,
//! ⟨F·cos θ⟩ = (4/3)E*√R·A1^{3/2}·f(x) and ⟨k_ts⟩ = 2E*√R·A1^{1/2}·s(x), where
//! f(x) = ⟨(δ/A1)^{3/2}·cos θ⟩ and s(x) = ⟨(δ/A1)^{1/2}⟩ over θ; their ratio
//! ⟨F·cos θ⟩/(A1·⟨k_ts⟩) = (2/3)·f(x)/s(x), x/2 for a short tap, gives x, and ⟨k_ts⟩ gives
//! E*. That is the estimate's `indentation` and `reduced_modulus`; the closed forms are
//! beside them (`short_tap_*`), and the two agree as d/A1 → 0.
//!
//! k1 and k2 are the modes' tip-referred stiffnesses ([`super::Mode::tip_stiffness`]),
//! amplitudes are the tip's (m, peak). Both need the second mode's amplitude small against
//! d; `tests/bimodal.rs` measures them against the coupled engine from 1 MPa to 100 GPa.

use std::sync::LazyLock;

use std::f64::consts::{FRAC_PI_2, PI, SQRT_2, TAU};

/// The lever's constants the expressions need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BimodalLever {
    /// Mode 1's tip-referred stiffness k1 (N/m).
    pub k1: f64,
    /// Mode 1's quality factor Q1.
    pub q1: f64,
    /// Mode 2's tip-referred stiffness k2 (N/m).
    pub k2: f64,
    /// Mode 2's free resonance f2 (Hz).
    pub f2: f64,
    /// Tip radius R (m).
    pub tip_radius: f64,
}

/// What the instrument reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BimodalReading {
    /// Mode 1's free amplitude A01 (m, peak).
    pub free_amplitude: f64,
    /// Mode 1's amplitude A1 (m, peak).
    pub amplitude: f64,
    /// Mode 1's phase lag φ1 (rad): π/2 free at resonance, below it in repulsive tapping.
    pub phase_lag: f64,
    /// Mode 2's frequency shift Δf2 (Hz; positive on a repulsive contact).
    pub frequency_shift: f64,
}

/// What the expressions give.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BimodalEstimate {
    /// The first mode's virial ⟨F·cos θ⟩ = k1·A01·cos φ1/(2Q1) (N): the tip's mean force
    /// ⟨F⟩ for a short tap.
    pub mean_force: f64,
    /// The contact's mean stiffness ⟨k_ts⟩ (N/m).
    pub mean_stiffness: f64,
    /// The deepest indentation d (m), the Hertz swing solved whole (module docs).
    pub indentation: f64,
    /// The reduced (effective) modulus E* (Pa), the Hertz swing solved whole:
    /// 1/E* = (1 − ν_t²)/E_t + (1 − ν_s²)/E_s.
    pub reduced_modulus: f64,
    /// d by the published short-tap expression 2⟨F⟩/⟨k_ts⟩ (m).
    pub short_tap_indentation: f64,
    /// E* by the published short-tap expression (Pa).
    pub short_tap_modulus: f64,
}

/// A reading the expressions cannot take, named.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BimodalError {
    /// A constant or reading out of its range.
    #[error("{name} = {value} is out of range: allowed {allowed}")]
    Parameter {
        /// Which one (`k1`, `phase_lag`, …).
        name: &'static str,
        /// The value given.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// Readings no Hertz swing gives.
    #[error(
        "the readings put the indentation at d/A1 = {ratio:.3} by the short-tap expression, \
         beyond what a Hertz contact on a swing gives (at most 1.090, at d/A1 = 1.86, where \
         the tip hardly leaves the sample): mode 1's phase lag or mode 2's Δf2 is not a \
         Hertz contact's"
    )]
    BeyondSwing {
        /// 2⟨F·cos θ⟩/(A1·⟨k_ts⟩): d/A1 by the short-tap expression.
        ratio: f64,
    },
}

/// The bimodal AM-FM estimate for `reading` on `lever` (module docs).
pub fn estimate(
    lever: &BimodalLever,
    reading: &BimodalReading,
) -> Result<BimodalEstimate, BimodalError> {
    let positive = [
        ("k1", lever.k1),
        ("q1", lever.q1),
        ("k2", lever.k2),
        ("f2", lever.f2),
        ("tip_radius", lever.tip_radius),
        ("free_amplitude", reading.free_amplitude),
        ("amplitude", reading.amplitude),
        ("frequency_shift", reading.frequency_shift),
    ];
    for (name, value) in positive {
        if !(value.is_finite() && value > 0.0) {
            return Err(BimodalError::Parameter {
                name,
                value,
                allowed: if name == "frequency_shift" {
                    "> 0 (a repulsive contact raises the second resonance)"
                } else {
                    "finite and > 0"
                },
            });
        }
    }
    let cos = reading.phase_lag.cos();
    if !(reading.phase_lag.is_finite() && cos > 0.0) {
        return Err(BimodalError::Parameter {
            name: "phase_lag",
            value: reading.phase_lag,
            allowed: "within (−π/2, π/2) rad: repulsive tapping, below the free lag of π/2",
        });
    }
    let a1 = reading.amplitude;
    let mean_force = lever.k1 * reading.free_amplitude * cos / (2.0 * lever.q1);
    let mean_stiffness = 2.0 * lever.k2 * reading.frequency_shift / lever.f2;
    let short_tap_indentation = 2.0 * mean_force / mean_stiffness;
    let short_tap_modulus =
        mean_stiffness * (SQRT_2 * a1.sqrt()) / (lever.tip_radius.sqrt() * short_tap_indentation);
    let ratio = short_tap_indentation / a1;
    let (x, s) = SWING
        .solve(ratio)
        .ok_or(BimodalError::BeyondSwing { ratio })?;
    Ok(BimodalEstimate {
        mean_force,
        mean_stiffness,
        indentation: x * a1,
        reduced_modulus: mean_stiffness / (2.0 * (lever.tip_radius * a1).sqrt() * s),
        short_tap_indentation,
        short_tap_modulus,
    })
}

/// The Hertz swing's averages over x = d/A1 ∈ (0, 1.86], tabulated once: at each x the
/// short-tap ratio 2⟨F·cos θ⟩/(A1·⟨k_ts⟩) = (4/3)·f(x)/s(x) (x for a short tap) and
/// s(x) = ⟨(δ/A1)^{1/2}⟩ (x/(2√2) for a short tap), module docs.
struct SwingTable {
    /// x on a grid denser towards 0, where the contact is short.
    x: Vec<f64>,
    /// The short-tap ratio at each x, increasing.
    ratio: Vec<f64>,
    /// s(x).
    stiffness: Vec<f64>,
}

/// Grid points of [`SWING`]: its linear interpolation is within 1e-5 of the quadrature.
const SWING_POINTS: usize = 512;

static SWING: LazyLock<SwingTable> = LazyLock::new(SwingTable::new);

impl SwingTable {
    fn new() -> Self {
        let x: Vec<f64> = (0..=SWING_POINTS)
            .map(|i| 2.0 * (i as f64 / SWING_POINTS as f64).powi(2))
            .collect();
        let (mut ratio, mut stiffness) = (Vec::new(), Vec::new());
        for &x in &x {
            let (f, s) = swing_averages(x);
            let r = if x > 0.0 { 4.0 / 3.0 * f / s } else { 0.0 };
            // The ratio peaks near x = 1.86, where the contact spans most of the swing and
            // its top half pulls the virial down: beyond, one reading fits two depths.
            if ratio.last().is_some_and(|&last| r <= last) {
                break;
            }
            ratio.push(r);
            stiffness.push(s);
        }
        let mut x = x;
        x.truncate(ratio.len());
        Self {
            x,
            ratio,
            stiffness,
        }
    }

    /// x and s(x) where the ratio is `ratio`; `None` beyond the table's last.
    fn solve(&self, ratio: f64) -> Option<(f64, f64)> {
        // The table starts at x = 0 with both 0, and both grow as x there.
        let i = self.ratio.partition_point(|&r| r < ratio).max(1);
        if i >= self.ratio.len() {
            return None;
        }
        let w = (ratio - self.ratio[i - 1]) / (self.ratio[i] - self.ratio[i - 1]);
        let lerp = |v: &[f64]| v[i - 1] + w * (v[i] - v[i - 1]);
        Some((lerp(&self.x), lerp(&self.stiffness)))
    }
}

/// f(x) = ⟨(δ/A1)^{3/2}·cos θ⟩ and s(x) = ⟨(δ/A1)^{1/2}⟩ over a period, δ/A1 = x − (1 − cos θ)
/// where positive: θ = θ0·sin u over u ∈ (−π/2, π/2), θ0 the contact's half-width, which
/// makes both integrands smooth at the contact's ends, by the midpoint rule.
fn swing_averages(x: f64) -> (f64, f64) {
    const N: usize = 2048;
    if x <= 0.0 {
        return (0.0, 0.0);
    }
    let theta0 = (1.0 - x).max(-1.0).acos();
    let (mut f, mut s) = (0.0, 0.0);
    for i in 0..N {
        let u = -FRAC_PI_2 + (i as f64 + 0.5) * PI / N as f64;
        let theta = theta0 * u.sin();
        let delta = (x - (1.0 - theta.cos())).max(0.0);
        let weight = theta0 * u.cos();
        f += delta.powf(1.5) * theta.cos() * weight;
        s += delta.sqrt() * weight;
    }
    let scale = PI / N as f64 / TAU;
    (f * scale, s * scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reading a Hertz contact of `modulus` gives at depth `d` under a swing `a1`, its
    /// averages summed over a fine grid of θ independently of the table's quadrature: the
    /// virial ⟨F·cos θ⟩ sets cos φ1, ⟨k_ts⟩ sets Δf2. With the mean force ⟨F⟩.
    fn hertz_reading(
        lever: &BimodalLever,
        modulus: f64,
        a1: f64,
        d: f64,
    ) -> (BimodalReading, f64, f64) {
        let n = 2_000_000;
        let (mut force, mut virial, mut stiffness) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let theta = -PI + (i as f64 + 0.5) * TAU / n as f64;
            let delta = d - a1 * (1.0 - theta.cos());
            if delta > 0.0 {
                let f = 4.0 / 3.0 * modulus * lever.tip_radius.sqrt() * delta.powf(1.5);
                force += f;
                virial += f * theta.cos();
                stiffness += 2.0 * modulus * lever.tip_radius.sqrt() * delta.sqrt();
            }
        }
        let (force, virial, stiffness) =
            (force / n as f64, virial / n as f64, stiffness / n as f64);
        let free = 30e-9;
        let reading = BimodalReading {
            free_amplitude: free,
            amplitude: a1,
            phase_lag: (virial * 2.0 * lever.q1 / (lever.k1 * free)).acos(),
            frequency_shift: stiffness * lever.f2 / (2.0 * lever.k2),
        };
        (reading, force, stiffness)
    }

    const LEVER: BimodalLever = BimodalLever {
        k1: 20.0,
        q1: 100.0,
        k2: 800.0,
        f2: 626e3,
        tip_radius: 10e-9,
    };

    /// The closed form against the two steps it comes from, on a short tap: the published
    /// expressions give back its E* and d within the parabola's few per cent, and the mean
    /// force within the virial's.
    #[test]
    fn a_short_tap_inverts_by_the_published_expressions() {
        let (modulus, a1, d) = (1e9, 20e-9, 1.5e-9);
        let (reading, force, stiffness) = hertz_reading(&LEVER, modulus, a1, d);
        let e = estimate(&LEVER, &reading).unwrap();
        assert!(
            (e.mean_force / force - 1.0).abs() < 0.03,
            "⟨F⟩ {}",
            e.mean_force
        );
        assert!((e.mean_stiffness / stiffness - 1.0).abs() < 1e-12);
        // The short tap's error at d/A1 = 7.5 %: a few per cent.
        assert!(
            (e.short_tap_indentation / d - 1.0).abs() < 0.03,
            "d {}",
            e.short_tap_indentation
        );
        assert!(
            (e.short_tap_modulus / modulus - 1.0).abs() < 0.03,
            "E* {}",
            e.short_tap_modulus
        );
        let closed = 4.0
            * SQRT_2
            * (LEVER.k2 * reading.frequency_shift / LEVER.f2).powi(2)
            * LEVER.q1
            * a1.sqrt()
            / (LEVER.tip_radius.sqrt()
                * LEVER.k1
                * reading.free_amplitude
                * reading.phase_lag.cos());
        assert!((closed / e.short_tap_modulus - 1.0).abs() < 1e-12);
    }

    /// The whole swing solved gives back E* and d from a short tap to a tip that never
    /// leaves the sample, where the short-tap expressions drift by tens of per cent; the
    /// two agree as d/A1 → 0.
    #[test]
    fn the_whole_swing_inverts_to_its_modulus_at_any_depth() {
        let a1 = 20e-9;
        for (x, modulus) in [
            (1e-3, 100e9),
            (0.075, 1e9),
            (0.38, 10e6),
            (1.0, 1e6),
            (1.8, 1e6),
        ] {
            let d = x * a1;
            let (reading, _, _) = hertz_reading(&LEVER, modulus, a1, d);
            let e = estimate(&LEVER, &reading).unwrap();
            let short = e.short_tap_modulus / modulus - 1.0;
            eprintln!(
                "d/A1 {x}: E* {:+.2e}, d {:+.2e} relative; short tap {short:+.4}",
                e.reduced_modulus / modulus - 1.0,
                e.indentation / d - 1.0
            );
            assert!(
                (e.reduced_modulus / modulus - 1.0).abs() < 1e-4,
                "E* at d/A1 {x}"
            );
            assert!((e.indentation / d - 1.0).abs() < 1e-4, "d at d/A1 {x}");
            if x < 0.01 {
                assert!(short.abs() < 1e-3, "short tap at d/A1 {x}: {short}");
            } else if x > 0.3 {
                assert!(short > 0.1, "short tap at d/A1 {x}: {short}");
            }
        }
        // Beyond the whole swing: named.
        let (reading, _, _) = hertz_reading(&LEVER, 1e6, a1, 1.8 * a1);
        let deeper = BimodalReading {
            phase_lag: (reading.phase_lag.cos() * 1.1).acos(),
            ..reading
        };
        let err = estimate(&LEVER, &deeper).unwrap_err().to_string();
        assert!(
            err.contains("beyond what a Hertz contact on a swing gives"),
            "{err}"
        );
    }

    #[test]
    fn readings_it_cannot_take_are_named() {
        let lever = BimodalLever {
            k1: 20.0,
            q1: 100.0,
            k2: 800.0,
            f2: 626e3,
            tip_radius: 10e-9,
        };
        let reading = BimodalReading {
            free_amplitude: 30e-9,
            amplitude: 20e-9,
            phase_lag: 2.0,
            frequency_shift: 500.0,
        };
        let err = estimate(&lever, &reading).unwrap_err().to_string();
        assert!(err.starts_with("phase_lag = 2 is out of range"), "{err}");
        let err = estimate(
            &lever,
            &BimodalReading {
                frequency_shift: -3.0,
                ..reading
            },
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.starts_with("frequency_shift = -3 is out of range"),
            "{err}"
        );
    }
}
