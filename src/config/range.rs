//! Allowed intervals of numeric nodes, and how they read in messages and docs
//! (`0 < value ≤ 1e13`).

use std::fmt;

use super::quantity::number;

/// One end of an interval, in the node's unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bound {
    /// The limit itself.
    pub value: f64,
    /// Whether the limit itself is allowed.
    pub inclusive: bool,
}

/// The values a float node (or each entry of a list node) may take, in the node's unit.
/// Both ends are always finite; non-finite values are never allowed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// Lower end.
    pub min: Bound,
    /// Upper end.
    pub max: Bound,
}

impl Range {
    /// `min < value ≤ max`: the usual form for positive physical quantities.
    pub const fn above_up_to(min: f64, max: f64) -> Range {
        Range {
            min: Bound {
                value: min,
                inclusive: false,
            },
            max: Bound {
                value: max,
                inclusive: true,
            },
        }
    }

    /// `min < value < max`.
    pub const fn between(min: f64, max: f64) -> Range {
        Range {
            min: Bound {
                value: min,
                inclusive: false,
            },
            max: Bound {
                value: max,
                inclusive: false,
            },
        }
    }

    /// `min ≤ value ≤ max`.
    pub const fn closed(min: f64, max: f64) -> Range {
        Range {
            min: Bound {
                value: min,
                inclusive: true,
            },
            max: Bound {
                value: max,
                inclusive: true,
            },
        }
    }

    /// Whether `x` is finite and inside the interval.
    pub fn contains(&self, x: f64) -> bool {
        let above = if self.min.inclusive {
            x >= self.min.value
        } else {
            x > self.min.value
        };
        let below = if self.max.inclusive {
            x <= self.max.value
        } else {
            x < self.max.value
        };
        x.is_finite() && above && below
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let sign = |inclusive| if inclusive { "≤" } else { "<" };
        write!(
            f,
            "{} {} value {} {}",
            number(self.min.value),
            sign(self.min.inclusive),
            sign(self.max.inclusive),
            number(self.max.value)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_follow_inclusiveness() {
        let poisson = Range::between(-1.0, 0.5);
        assert!(!poisson.contains(-1.0) && !poisson.contains(0.5) && poisson.contains(0.28));
        assert_eq!(poisson.to_string(), "-1 < value < 0.5");
        let modulus = Range::above_up_to(0.0, 1e13);
        assert!(!modulus.contains(0.0) && modulus.contains(1e13));
        assert_eq!(modulus.to_string(), "0 < value ≤ 1e13");
        assert!(!Range::closed(1e3, 1e9).contains(f64::NAN));
        assert!(!Range::closed(1e3, 1e9).contains(f64::INFINITY));
    }
}
