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

/// DMT adhesion (physics.md §6): the van der Waals attraction of a sphere of radius R to a
/// flat, `−HR/(6(a0 − δ)²)` out of contact (δ < 0) and the constant `−HR/(6a0²)` in
/// contact, where it adds to the Hertz force (Derjaguin–Muller–Toporov).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adhesion {
    /// Hamaker constant H (J).
    pub hamaker: f64,
    /// Intermolecular distance a0 (m): where the attraction saturates.
    pub distance: f64,
}

impl Adhesion {
    /// HR/6 (N·m) of a tip of radius `radius` (m): the attraction is this over a squared
    /// distance.
    pub fn strength(&self, radius: f64) -> f64 {
        self.hamaker * radius / 6.0
    }

    /// The adhesion force HR/(6a0²) (N, a magnitude): the pull in contact, and the most
    /// negative force out of it.
    pub fn pull_off(&self, radius: f64) -> f64 {
        self.strength(radius) / (self.distance * self.distance)
    }

    /// Attractive force (N, ≤ 0) of a tip of radius `radius` (m) at indentation `delta`
    /// (m; negative: a gap of −δ to the surface).
    pub fn force(&self, radius: f64, delta: f64) -> f64 {
        let d = self.distance - delta.min(0.0);
        -self.strength(radius) / (d * d)
    }
}
