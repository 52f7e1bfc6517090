//! Hertz contact of a spherical tip on a flat sample (the paper's Eq. 11–12, with the
//! prefactor corrected as physics.md §3 explains).

use std::f64::consts::PI;

/// An isotropic elastic solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Elastic {
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson ratio ν (1).
    pub poisson: f64,
}

impl Elastic {
    /// Compliance (1 − ν²)/E (1/Pa).
    fn compliance(&self) -> f64 {
        (1.0 - self.poisson * self.poisson) / self.youngs_modulus
    }
}

/// Repulsive Hertz contact between a sphere of radius R and a flat.
///
/// Force F = κ_eff·√R·δ^{3/2} for indentation δ > 0, with κ_eff = (4/3)·E* and
/// 1/E* = (1 − ν_tip²)/E_tip + (1 − ν_s²)/E_s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HertzContact {
    /// Reduced modulus E* (Pa).
    pub reduced_modulus: f64,
    /// Tip radius R (m).
    pub radius: f64,
}

impl HertzContact {
    /// Contact of a tip of radius `radius` (m) made of `tip` with a `sample`.
    pub fn new(tip: Elastic, sample: Elastic, radius: f64) -> Self {
        Self {
            reduced_modulus: 1.0 / (tip.compliance() + sample.compliance()),
            radius,
        }
    }

    /// κ_eff = (4/3)·E* (Pa).
    pub fn kappa(&self) -> f64 {
        4.0 / 3.0 * self.reduced_modulus
    }

    /// Prefactor κ_eff·√R of δ^{3/2} (N/m^{3/2}).
    pub fn stiffness_coefficient(&self) -> f64 {
        self.kappa() * self.radius.sqrt()
    }

    /// Repulsive force (N) at indentation `delta` (m); zero out of contact.
    pub fn force(&self, delta: f64) -> f64 {
        if delta > 0.0 {
            self.stiffness_coefficient() * delta * delta.sqrt()
        } else {
            0.0
        }
    }

    /// Indentation (m) at which the force is `force` (N).
    pub fn indentation(&self, force: f64) -> f64 {
        (force.max(0.0) / self.stiffness_coefficient()).powf(2.0 / 3.0)
    }

    /// Contact radius a = (3FR/(4E*))^{1/3} (m) under force `force` (N).
    pub fn contact_radius(&self, force: f64) -> f64 {
        (3.0 * force * self.radius / (4.0 * self.reduced_modulus)).cbrt()
    }

    /// Maximum (central) Hertz pressure 3F/(2πa²) (Pa) under force `force` (N).
    pub fn max_pressure(&self, force: f64) -> f64 {
        let a = self.contact_radius(force);
        if a > 0.0 {
            3.0 * force / (2.0 * PI * a * a)
        } else {
            0.0
        }
    }
}
