//! The physical model the settings describe: settings (SI, validated) → physics types.

use crate::config::{Material, Settings};
use crate::physics::beam::BeamError;
use crate::physics::{
    Adhesion, Cantilever, CoupledProblem, Elastic, HertzContact, ImpactOscillator,
};

/// The cantilever of `/cantilever/...`.
pub fn cantilever(settings: &Settings) -> Result<Cantilever, BeamError> {
    let c = &settings.cantilever;
    Cantilever::new(c.f1, c.k, &c.q, c.extra_modes)
}

/// The free tip deflection amplitude (m) per metre of base (piezo) amplitude at the drive
/// frequency `frequency` (Hz): the base's inertial load U·Ω² drives mode n through its
/// participation Pn, so |w(L)|/U = Ω²·|Σn φn(L)·Pn·Hn(Ω)/ωn²| (the synthesiser's drive).
pub fn free_response_per_base(cantilever: &Cantilever, frequency: f64) -> f64 {
    let omega = 2.0 * std::f64::consts::PI * frequency;
    let tip: rustfft::num_complex::Complex64 = cantilever
        .modes
        .iter()
        .map(|m| m.transfer(omega) * (m.participation * m.tip_value / (m.omega * m.omega)))
        .sum();
    omega * omega * tip.norm()
}

/// Largest indentation, as a fraction of the tip radius, for which the Hertz contact (small
/// strain, paraboloidal tip) is taken as within its range.
pub const HERTZ_RANGE: f64 = 0.1;

/// Where the operating point of `settings` leaves the model's range, in words (empty when it
/// does not): the 1-DOF orbit's maximum indentation against the tip radius. Costs one 1-DOF
/// solve (milliseconds): call it when the settings change, not per message.
pub fn range_warnings(settings: &Settings) -> Vec<String> {
    let Ok(cantilever) = cantilever(settings) else {
        return Vec::new();
    };
    let oscillator = impact_oscillator(settings, &cantilever, settings.sample);
    let Ok(solution) = oscillator.solve() else {
        return Vec::new();
    };
    let radius = settings.cantilever.tip_radius;
    let ratio = solution.max_indentation / radius;
    if ratio > HERTZ_RANGE {
        vec![format!(
            "the tip indents the sample by {:.3} nm, {:.0} % of the tip radius {:.1} nm \
             (/cantilever/tip_radius): beyond the Hertz contact's small-strain range (about \
             {:.0} %), so forces and harmonics are qualitative here (a softer sample needs a \
             smaller /drive/free_amplitude or a larger /surface/distance)",
            solution.max_indentation * 1e9,
            100.0 * ratio,
            radius * 1e9,
            100.0 * HERTZ_RANGE
        )]
    } else {
        Vec::new()
    }
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

/// The DMT adhesion of `[adhesion]`, `None` while it is off.
pub fn adhesion(settings: &Settings) -> Option<Adhesion> {
    let a = &settings.adhesion;
    a.enable.then_some(Adhesion {
        hamaker: a.hamaker,
        distance: a.distance,
    })
}

/// The coupled tapping problem (physics.md §6) of the settings with `sample` under the tip,
/// driven at `drive_frequency` (Hz; the synthesiser's realised frequency may differ from the
/// configured one by its phase word's rounding), with the adhesion of `[adhesion]`.
pub fn coupled_problem(
    settings: &Settings,
    cantilever: &Cantilever,
    sample: Material,
    drive_frequency: f64,
) -> CoupledProblem {
    CoupledProblem::new(
        cantilever,
        drive_frequency,
        settings.drive.free_amplitude,
        settings.surface.distance,
        impact_oscillator(settings, cantilever, sample).contact,
    )
    .with_adhesion(adhesion(settings))
}
