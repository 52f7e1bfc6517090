//! The physical model the settings describe: settings (SI, validated) → physics types.

use crate::config::{Material, Settings};
use crate::physics::beam::BeamError;
use crate::physics::{Cantilever, Elastic, HertzContact, ImpactOscillator};

/// The cantilever of `/cantilever/...`.
pub fn cantilever(settings: &Settings) -> Result<Cantilever, BeamError> {
    let c = &settings.cantilever;
    Cantilever::new(c.f1, c.k, &c.q, c.extra_modes)
}

/// An elastic solid from a material table.
pub fn elastic(material: Material) -> Elastic {
    Elastic {
        youngs_modulus: material.youngs_modulus,
        poisson: material.poisson,
    }
}

/// The 1-DOF tapping problem of the settings with `sample` under the tip; the point mass
/// has the cantilever's k, f1 and Q1.
pub fn impact_oscillator(
    settings: &Settings,
    cantilever: &Cantilever,
    sample: Material,
) -> ImpactOscillator {
    ImpactOscillator {
        k: settings.cantilever.k,
        f1: settings.cantilever.f1,
        q: cantilever.fundamental().q,
        drive_frequency: settings.drive.frequency,
        free_amplitude: settings.drive.free_amplitude,
        surface_distance: settings.surface.distance,
        contact: HertzContact::new(
            elastic(settings.tip),
            elastic(sample),
            settings.cantilever.tip_radius,
        ),
    }
}
