//! The physical model the settings describe: settings (SI, validated) → physics types.

use crate::config::quantity::{number, quantity};
use crate::config::{Material, NodeError, PidTarget, Settings};
use crate::control::{PidError, PidSettings};
use crate::physics::beam::BeamError;
use crate::physics::impact::ImpactError;
use crate::physics::{
    Adhesion, Cantilever, CoupledProblem, Elastic, HertzContact, ImpactOscillator, ImpactSolution,
};

/// Whether the physics of `settings` can run: the checks no node's range can express,
/// which need the model (a cantilever built from the Q values, the 1-DOF tapping orbit,
/// a tune's free amplitude at every point). `Settings::validate` (the schema) comes first;
/// the config loader runs only that, and every command and every change of a running
/// daemon runs this after it, off the request path. Its cost is bounded whatever the
/// settings (milliseconds at an instrument's settings, at most the orbit solver's
/// transient budget, a fraction of a second): a setting it cannot decide is refused with
/// an error naming the nodes, never waited for.
pub fn check(settings: &Settings) -> Result<Feasible, NodeError> {
    let solution = check_orbit(settings)?;
    check_tune(settings)?;
    check_pids(settings)?;
    Ok(Feasible {
        range_warnings: warnings_of(settings, &solution),
    })
}

/// What [`check`] learnt of settings it accepts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Feasible {
    /// Where the operating point leaves the model's range ([`range_warnings`]).
    pub range_warnings: Vec<String>,
}

fn invalid(path: impl Into<String>, message: String) -> NodeError {
    NodeError::InvalidValue {
        path: path.into(),
        message,
    }
}

/// A cantilever that can be built from `[cantilever]` and a 1-DOF tapping problem whose
/// periodic orbit the solver finds within its budget (`SolveOptions::max_transient_periods`).
fn check_orbit(s: &Settings) -> Result<ImpactSolution, NodeError> {
    let cantilever = cantilever(s).map_err(|e| {
        invalid(
            "/cantilever/extra_modes",
            format!(
                "/cantilever/q = {} with /cantilever/extra_modes = {} gives no cantilever: {e}",
                list_of_numbers(&s.cantilever.q),
                s.cantilever.extra_modes
            ),
        )
    })?;
    let oscillator = impact_oscillator(s, &cantilever, s.sample);
    oscillator.solve().map_err(|e| {
        // A transient longer than the solver's budget is Q's doing: name it first.
        let (path, hint) = match e {
            ImpactError::NoSteadyOrbit { .. } => (
                "/cantilever/q",
                "lower Q1 (/cantilever/q), or bring /drive/free_amplitude and \
                 /surface/distance closer to an instrument's",
            ),
            _ => (
                "/cantilever",
                "bring these closer to an instrument's (the embedded default is one)",
            ),
        };
        invalid(
            path,
            format!(
                "the 1-DOF tapping problem has no periodic solution ({e}) for /cantilever/f1 = \
                 {}, /cantilever/k = {}, Q1 = {}, /drive/frequency = {}, \
                 /drive/free_amplitude = {}, /surface/distance = {} (with \
                 /cantilever/tip_radius, [tip] and [sample]): {hint}",
                quantity(s.cantilever.f1, "Hz"),
                quantity(s.cantilever.k, "N/m"),
                number(cantilever.fundamental().q),
                quantity(s.drive.frequency, "Hz"),
                quantity(s.drive.free_amplitude, "m"),
                quantity(s.surface.distance, "m"),
            ),
        )
    })
}

/// A short list of numbers for a message: `[100, 417, 340]`, cut after 8 entries.
fn list_of_numbers(list: &[f64]) -> String {
    let shown: Vec<String> = list.iter().take(8).map(|x| number(*x)).collect();
    let more = if list.len() > 8 {
        format!(", … ({} entries)", list.len())
    } else {
        String::new()
    };
    format!("[{}{more}]", shown.join(", "))
}

/// The controller settings of PID unit `index` (`/pids/N/*`): its period dt is one drive
/// period (it runs once per period), its centre the output's present value
/// (`/surface/distance`) within its limits. `None` for an index the settings lack.
pub fn pid_settings(s: &Settings, index: usize) -> Option<PidSettings> {
    let pid = s.pids.get(index)?;
    let present = match pid.output {
        PidTarget::SurfaceDistance => s.surface.distance,
        PidTarget::DriveFrequency => s.drive.frequency,
        PidTarget::DriveAmplitude => s.drive.free_amplitude,
        PidTarget::Drive2Frequency => s.drive2.frequency,
        PidTarget::Drive2Amplitude => s.drive2.free_amplitude,
    };
    Some(PidSettings {
        setpoint: pid.setpoint,
        p: pid.p,
        i: pid.i,
        d: pid.d,
        d_bandwidth: pid.d_bandwidth,
        output_min: pid.output_min,
        output_max: pid.output_max,
        rate_limit: (pid.rate > 0.0).then_some(pid.rate),
        // Not `clamp`: it panics on crossed limits, which `validate` names instead.
        center: present.max(pid.output_min).min(pid.output_max),
        dt: 1.0 / s.drive.frequency,
    })
}

/// Every enabled PID unit's gains and limits as its controller takes them
/// ([`PidSettings::validate`]): the error names the node (`/pids/N/p`, …) and the allowed
/// range. Part of [`check`], and run alone for changes that leave the orbit alone.
pub fn check_pids(s: &Settings) -> Result<(), NodeError> {
    for (index, _) in s.pids.iter().enumerate().filter(|(_, p)| p.enable) {
        let Some(settings) = pid_settings(s, index) else {
            continue;
        };
        if let Err(e) = settings.validate() {
            return Err(pid_error(index, &e));
        }
    }
    Ok(())
}

/// A controller's refusal as the node's: `rate_limit` is `/pids/N/rate`, the period dt is
/// the drive's.
fn pid_error(index: usize, e: &PidError) -> NodeError {
    let node = match e.parameter {
        "rate_limit" => "rate",
        "dt" => {
            return invalid(
                "/drive/frequency",
                format!(
                    "/pids/{index} runs once per drive period, and /drive/frequency gives it \
                     dt = {}: allowed {}",
                    number(e.value),
                    e.allowed
                ),
            );
        }
        // The centre is the output's present value, clamped into the limits: only crossed
        // limits make it fail, which `output_min` names first.
        "center" => "output_min",
        other => other,
    };
    let path = format!("/pids/{index}/{node}");
    invalid(
        path.clone(),
        format!(
            "{path} = {} is out of range while /pids/{index}/enable is true: allowed {}",
            number(e.value),
            e.allowed
        ),
    )
}

/// For a tune of the drive frequency at a constant base amplitude: the free amplitude at
/// every point within its allowed range (part of [`check`]; alone for a change that leaves
/// the orbit's nodes as they were).
pub fn check_tune(s: &Settings) -> Result<(), NodeError> {
    let w = &s.sweeper;
    if !w.enable {
        return Ok(());
    }
    if w.parameter == crate::config::SweepParameter::DriveFrequency
        && let Ok(cantilever) = cantilever(s)
    {
        let base = s.drive.free_amplitude / free_response_per_base(&cantilever, s.drive.frequency);
        let n = w.points as usize;
        let log = w.scale == crate::config::SweepScale::Log;
        let free_max = crate::config::registry::node("/drive/free_amplitude")
            .map(|spec| spec.bounds(s).1.as_f64().unwrap_or(f64::INFINITY))
            .unwrap_or(f64::INFINITY);
        for p in crate::sweep::points(w.start, w.stop, n, log, true, false) {
            let free = base * free_response_per_base(&cantilever, p.value);
            if free > free_max {
                return Err(invalid(
                    "/sweeper/stop",
                    format!(
                        "a tune from /sweeper/start = {} to /sweeper/stop = {} Hz at the base \
                         amplitude that gives /drive/free_amplitude = {} at /drive/frequency \
                         = {} reaches a free amplitude of {} at {}, above the largest allowed \
                         {}: lower /drive/free_amplitude or narrow the sweep",
                        number(w.start),
                        number(w.stop),
                        quantity(s.drive.free_amplitude, "m"),
                        quantity(s.drive.frequency, "Hz"),
                        quantity(free, "m"),
                        quantity(p.value, "Hz"),
                        quantity(free_max, "m")
                    ),
                ));
            }
        }
    }
    Ok(())
}

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
/// solve (milliseconds; at most the solver's transient budget): [`check`] gives them too.
pub fn range_warnings(settings: &Settings) -> Vec<String> {
    let Ok(cantilever) = cantilever(settings) else {
        return Vec::new();
    };
    let oscillator = impact_oscillator(settings, &cantilever, settings.sample);
    let Ok(solution) = oscillator.solve() else {
        return Vec::new();
    };
    warnings_of(settings, &solution)
}

/// [`range_warnings`] of the 1-DOF orbit `solution` of `settings`.
fn warnings_of(settings: &Settings, solution: &ImpactSolution) -> Vec<String> {
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
