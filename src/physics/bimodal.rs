//! Bimodal AM-FM: the first mode under amplitude modulation (its amplitude A1 and phase
//! lag φ1 against a free amplitude A01), the second driven at a small amplitude whose
//! frequency shift Δf2 reads the contact's stiffness; together they give the tip's mean
//! force, the contact's mean stiffness, the indentation and the reduced modulus E*
//! (Herruzo, Perrino & Garcia, Nat. Commun. 5, 3126 (2014); Benaglia et al., Nat. Protoc.
//! 13, 2890 (2018)), derived here with this project's conventions:
//!
//! - The first mode's virial: its tap, short and at the lower turning point, takes
//!   ⟨F⟩ = k1·A01·cos φ1/(2Q1) (φ1 = 90° free, below 90° in repulsive tapping).
//! - The second mode, of small amplitude, feels the contact's stiffness averaged over the
//!   first's swing: Δf2/f2 = ⟨k_ts⟩/(2k2), so ⟨k_ts⟩ = 2k2·Δf2/f2.
//! - A Hertz contact F = (4/3)E*√R·δ^{3/2} at the bottom of a swing of amplitude A1 lasts
//!   while δ = d − A1·θ²/2 > 0 (d the deepest indentation), so over a period
//!   ⟨F⟩ = E*√R·d²/(2√(2A1)) and ⟨k_ts⟩ = E*√R·d/√(2A1).
//! - Hence d = 2⟨F⟩/⟨k_ts⟩ and E* = ⟨k_ts⟩·√(2A1)/(√R·d)
//!   = 4√2·(k2·Δf2/f2)²·Q1·√A1/(√R·k1·A01·cos φ1).
//!
//! k1 and k2 are the modes' tip-referred stiffnesses ([`super::Mode::tip_stiffness`]),
//! amplitudes are the tip's (m, peak). The expressions hold where the contact is short
//! (d ≪ A1) and the second mode's amplitude small against d; `tests/bimodal.rs` measures
//! them against the coupled engine from 1 MPa to 100 GPa.

use std::f64::consts::SQRT_2;

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
    /// The tip's mean force ⟨F⟩ (N).
    pub mean_force: f64,
    /// The contact's mean stiffness ⟨k_ts⟩ (N/m).
    pub mean_stiffness: f64,
    /// The deepest indentation d (m).
    pub indentation: f64,
    /// The reduced (effective) modulus E* (Pa): 1/E* = (1 − ν_t²)/E_t + (1 − ν_s²)/E_s.
    pub reduced_modulus: f64,
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
    let mean_force = lever.k1 * reading.free_amplitude * cos / (2.0 * lever.q1);
    let mean_stiffness = 2.0 * lever.k2 * reading.frequency_shift / lever.f2;
    let indentation = 2.0 * mean_force / mean_stiffness;
    let reduced_modulus = mean_stiffness * (SQRT_2 * reading.amplitude.sqrt())
        / (lever.tip_radius.sqrt() * indentation);
    Ok(BimodalEstimate {
        mean_force,
        mean_stiffness,
        indentation,
        reduced_modulus,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form against the two steps it comes from, and a Hertz contact's averages
    /// integrated numerically over a swing: the expressions give back its E* and d.
    #[test]
    fn averages_of_a_hertz_swing_invert_to_its_modulus() {
        let (modulus, radius, a1, d): (f64, f64, f64, f64) = (1e9, 10e-9, 20e-9, 1.5e-9);
        // ⟨F⟩ and ⟨k_ts⟩ over θ ∈ [−π, π] of the tip at −A1·cos θ into a surface d above
        // its lowest point (exact, not the parabola the expressions use).
        let n = 2_000_000;
        let (mut force, mut stiffness) = (0.0, 0.0);
        for i in 0..n {
            let theta = -std::f64::consts::PI + (i as f64 + 0.5) * std::f64::consts::TAU / n as f64;
            let delta = d - a1 * (1.0 - theta.cos());
            if delta > 0.0 {
                force += 4.0 / 3.0 * modulus * radius.sqrt() * delta.powf(1.5);
                stiffness += 2.0 * modulus * radius.sqrt() * delta.sqrt();
            }
        }
        let (force, stiffness) = (force / n as f64, stiffness / n as f64);
        let lever = BimodalLever {
            k1: 20.0,
            q1: 100.0,
            k2: 800.0,
            f2: 626e3,
            tip_radius: radius,
        };
        let free = 30e-9;
        // The reading these averages give: cos φ1 from ⟨F⟩, Δf2 from ⟨k_ts⟩.
        let reading = BimodalReading {
            free_amplitude: free,
            amplitude: a1,
            phase_lag: (force * 2.0 * lever.q1 / (lever.k1 * free)).acos(),
            frequency_shift: stiffness * lever.f2 / (2.0 * lever.k2),
        };
        let e = estimate(&lever, &reading).unwrap();
        assert!((e.mean_force / force - 1.0).abs() < 1e-12);
        assert!((e.mean_stiffness / stiffness - 1.0).abs() < 1e-12);
        // The parabola's error at d/A1 = 7.5 %: a few per cent.
        assert!(
            (e.indentation / d - 1.0).abs() < 0.03,
            "d {}",
            e.indentation
        );
        assert!(
            (e.reduced_modulus / modulus - 1.0).abs() < 0.03,
            "E* {}",
            e.reduced_modulus
        );
        let closed = 4.0
            * SQRT_2
            * (lever.k2 * reading.frequency_shift / lever.f2).powi(2)
            * lever.q1
            * a1.sqrt()
            / (radius.sqrt() * lever.k1 * free * reading.phase_lag.cos());
        assert!((closed / e.reduced_modulus - 1.0).abs() < 1e-12);
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
