//! The coupled orbit search (physics.md §6) on the cases a user sets up: the orbits the
//! fixed-transient Newton search lost are found; where an attractive and a repulsive orbit
//! coexist, the approach from far and the contact start find one each and name them; a grid
//! of preset levers, samples, set-points and adhesion converges everywhere within its budget
//! or says why not.
//!
//! Each orbit is checked against invariants no solver can fake: a fixed point (residual),
//! stability from the exact Floquet multipliers, their product against Liouville's
//! `exp(−Σ 2γnωn T)`, and the energy balance of a period.

use ftafm::config::{Settings, default_settings, load_with_presets};
use ftafm::model;
use ftafm::physics::{Branch, CoupledOrbit, CoupledProblem, SearchLimits};

fn problem(s: &Settings) -> CoupledProblem {
    let c = model::cantilever(s).unwrap();
    model::coupled_problem(s, &c, s.sample, s.drive.frequency)
}

/// A lever (f1 Hz, k N/m, Q per mode, tip radius m) on a sample, at a free amplitude and
/// set-point ratio, with or without adhesion.
fn settings(
    lever: (f64, f64, &[f64], f64),
    e: f64,
    amplitude: f64,
    ratio: f64,
    adhesion: bool,
) -> Settings {
    let mut s = default_settings();
    (s.cantilever.f1, s.cantilever.k, s.cantilever.tip_radius) = (lever.0, lever.1, lever.3);
    s.cantilever.q = lever.2.to_vec();
    s.drive.frequency = lever.0;
    s.sample.youngs_modulus = e;
    s.drive.free_amplitude = amplitude;
    s.surface.distance = ratio * amplitude;
    s.adhesion.enable = adhesion;
    s
}

/// The invariants of a stable period-1 orbit.
fn check(s: &Settings, o: &CoupledOrbit, what: &str) {
    assert!(o.period_one, "{what}: not a stable period-1 orbit: {o:?}");
    assert!(o.residual < 1e-9, "{what}: residual {:e}", o.residual);
    assert!(o.floquet_max < 1.0, "{what}: multiplier {}", o.floquet_max);
    let c = model::cantilever(s).unwrap();
    let t = 1.0 / s.drive.frequency;
    let liouville = (-c
        .modes
        .iter()
        .map(|m| 2.0 * m.gamma * m.omega * t)
        .sum::<f64>())
    .exp();
    assert!(
        (o.floquet_product / liouville - 1.0).abs() < 1e-3,
        "{what}: Floquet product {:e}, Liouville {liouville:e}",
        o.floquet_product
    );
    let balance = o.drive_work - o.damping_work - o.base_contact_work;
    assert!(
        balance.abs() < 1e-4 * o.drive_work,
        "{what}: energy balance {balance:e} of {:e} J",
        o.drive_work
    );
}

/// The orbit of `s` (`what` names it), checked by [`check`] and timed; or the solver's
/// reason, named.
fn attempt(s: &Settings, what: &str) -> Result<(), String> {
    let started = std::time::Instant::now();
    match problem(s).solve(8) {
        Ok(o) => {
            eprintln!(
                "{what}: {:?}, F {:.3} nN, {} periods, {:.2} s",
                o.branch,
                o.max_force * 1e9,
                o.periods,
                started.elapsed().as_secs_f64()
            );
            check(s, &o, what);
            Ok(())
        }
        Err(e) => {
            eprintln!("{what}: {e} ({:.2} s)", started.elapsed().as_secs_f64());
            Err(format!("{what}: {e}"))
        }
    }
}

/// Every failure is one of the documented reasons; none is a bare non-convergence.
fn assert_documented(failures: &[String]) {
    let undocumented: Vec<_> = failures
        .iter()
        .filter(|f| !(f.contains("period 2") || f.contains("did not settle")))
        .collect();
    assert!(undocumented.is_empty(), "{undocumented:#?}");
}

const PAPER_Q: [f64; 5] = [100.0, 417.0, 340.0, 200.0, 26.0];

/// A 300 kHz lever whose slowest Floquet multiplier is 0.992 (a few hundred periods of
/// transient do not reach Newton's basin), and the default lever with adhesion at small
/// amplitudes: cases a fixed transient followed by Newton gave up on.
#[test]
fn the_orbits_a_fixed_transient_lost_are_found() {
    let stiff: (f64, f64, &[f64], f64) = (300e3, 40.0, &[400.0, 600.0, 500.0, 300.0, 100.0], 8e-9);
    let default: (f64, f64, &[f64], f64) = (100e3, 20.0, &PAPER_Q, 10e-9);
    for (what, s) in [
        (
            "300 kHz on fused silica, 12 nm of 20",
            settings(stiff, 72.7e9, 20e-9, 0.6, false),
        ),
        (
            "default lever, adhesion, 7 nm of 10",
            settings(default, 129e9, 10e-9, 0.7, true),
        ),
    ] {
        let o = problem(&s)
            .solve(8)
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        eprintln!(
            "{what}: F {:.2} nN, θ {:.2}°, {:?}, largest multiplier {:.4}, {} periods",
            o.max_force * 1e9,
            o.phase_shift_deg(),
            o.branch,
            o.floquet_max,
            o.periods
        );
        check(&s, &o, what);
        assert_eq!(o.branch, Branch::Repulsive, "{what}");
    }
}

/// The tap300 lever with adhesion at a 4 nm free amplitude, set-point 3 nm: an approach
/// from far stays on the attractive orbit, while a tip that meets the surface at full swing
/// taps on the repulsive one. Both are stable, both are found, and each is named.
#[test]
fn coexisting_branches_are_both_found_and_named() {
    let tap300: (f64, f64, &[f64], f64) =
        (300e3, 40.0, &[500.0, 2085.0, 1700.0, 1000.0, 130.0], 8e-9);
    let s = settings(tap300, 129e9, 4e-9, 0.75, true);
    let p = problem(&s);
    let approached = p.solve(8).unwrap();
    let contact = p.solve_from_contact(8, SearchLimits::default()).unwrap();
    eprintln!(
        "approach: {:?} mean force {:.3e} N, θ {:.2}°; contact start: {:?} mean force {:.3e} N, θ {:.2}°",
        approached.branch,
        approached.force_coefficients[0].re,
        approached.phase_shift_deg(),
        contact.branch,
        contact.force_coefficients[0].re,
        contact.phase_shift_deg()
    );
    check(&s, &approached, "approach");
    check(&s, &contact, "contact start");
    assert_eq!(approached.branch, Branch::Attractive);
    assert!(approached.force_coefficients[0].re < 0.0 && approached.jumps.is_empty());
    assert_eq!(contact.branch, Branch::Repulsive);
    assert!(contact.force_coefficients[0].re > 0.0);
    // In the attractive regime the tip lags the drive more than the free lever, in the
    // repulsive one less (θ above and below zero, García & San Paulo 1999).
    assert!(approached.phase_shift > contact.phase_shift);
}

/// The same lever approached further: the attractive branch ends and the approach jumps to
/// the repulsive one, and says where.
#[test]
fn an_approach_past_the_end_of_the_attractive_branch_reports_its_jump() {
    let tap300: (f64, f64, &[f64], f64) =
        (300e3, 40.0, &[500.0, 2085.0, 1700.0, 1000.0, 130.0], 8e-9);
    let s = settings(tap300, 129e9, 8e-9, 0.8, true);
    let o = problem(&s).solve(8).unwrap();
    check(&s, &o, "tap300, adhesion, 6.4 nm of 8");
    assert_eq!(o.branch, Branch::Repulsive);
    let jump = o.jumps.first().expect("a jump on the way");
    eprintln!("jumps: {:?}", o.jumps);
    assert_eq!(
        (jump.from, jump.to),
        (Branch::Attractive, Branch::Repulsive)
    );
    assert!(jump.distance > s.surface.distance && jump.distance < s.drive.free_amplitude);
}

/// Where the attractive branch has an unstable orbit beside its stable one (tap300 with
/// adhesion, 4 nm free, set-point ratios 0.78–0.79: a saddle whose largest multiplier is
/// 1.05), the approach's steps stay on the stable orbit, as a quasi-static approach does (a
/// walk in steps of 0.0025 of the ratio from 0.9 to 0.7 never leaves it), instead of
/// landing on the saddle and following the motion off it to the repulsive branch.
#[test]
fn an_approach_steps_past_an_unstable_orbit_of_its_branch() {
    let tap300: (f64, f64, &[f64], f64) =
        (300e3, 40.0, &[500.0, 2085.0, 1700.0, 1000.0, 130.0], 8e-9);
    let s = settings(tap300, 129e9, 4e-9, 0.785, true);
    let o = problem(&s).solve(8).unwrap();
    check(&s, &o, "tap300, adhesion, 3.14 nm of 4");
    assert_eq!(o.branch, Branch::Attractive, "jumps: {:?}", o.jumps);
    assert!(o.jumps.is_empty(), "{:?}", o.jumps);
}

/// A search stops within its budget of periods, and on a cancel flag, with the reason.
#[test]
fn a_search_keeps_its_budget_and_stops_when_cancelled() {
    let s = settings((100e3, 20.0, &PAPER_Q, 10e-9), 129e9, 30e-9, 0.5, false);
    let p = problem(&s);
    let small = SearchLimits {
        max_periods: 40,
        cancel: None,
    };
    let err = p.solve_with(8, small).unwrap_err();
    assert!(
        err.to_string().contains("budget of 40 drive periods"),
        "{err}"
    );
    let cancel = std::sync::atomic::AtomicBool::new(true);
    let cancelled = SearchLimits {
        max_periods: 1000,
        cancel: Some(&cancel),
    };
    let err = p.solve_with(8, cancelled).unwrap_err();
    assert!(err.to_string().contains("cancelled"), "{err}");
}

/// Every preset lever on a hard and a soft preset sample, at set-point ratios across the
/// range, with adhesion off and on: each point converges to a stable period-1 orbit within
/// the default budget, or fails with one of the documented reasons. CI runs one point per
/// lever (a hard sample in hard tapping, or a soft one with adhesion in light tapping);
/// `FTAFM_ORBIT_GRID=full` runs every preset sample at five ratios, adhesion off and on
/// (240 points, several minutes).
#[test]
fn the_preset_grid_converges_or_says_why() {
    let full = std::env::var("FTAFM_ORBIT_GRID").is_ok_and(|v| v == "full");
    let levers = ["tap300", "tap150", "multi75", "ac240"];
    let samples: &[&str] = if full {
        &[
            "silicon",
            "fused_silica",
            "polystyrene",
            "pdms",
            "mica",
            "hopg",
        ]
    } else {
        &["silicon", "polystyrene"]
    };
    let ratios: &[f64] = if full {
        &[0.3, 0.5, 0.7, 0.85, 0.95]
    } else {
        &[0.3, 0.85]
    };
    let mut failures = Vec::new();
    let mut points = 0;
    for (l, lever) in levers.iter().enumerate() {
        for (m, sample) in samples.iter().enumerate() {
            for (r, &ratio) in ratios.iter().enumerate() {
                for adhesion in [false, true] {
                    // CI: per lever, silicon at 0.3 without adhesion or polystyrene at 0.85
                    // with it, alternately.
                    let ci_point = m == r && usize::from(adhesion) == m && m == l % 2;
                    if !(full || ci_point) {
                        continue;
                    }
                    let names = [lever.to_string(), sample.to_string()];
                    let mut s = load_with_presets(&names, None).unwrap();
                    s.surface.distance = ratio * s.drive.free_amplitude;
                    s.adhesion.enable = adhesion;
                    let what = format!("{lever} on {sample}, ratio {ratio}, adhesion {adhesion}");
                    points += 1;
                    failures.extend(attempt(&s, &what).err());
                }
            }
        }
    }
    assert_documented(&failures);
    eprintln!(
        "{points} points, {} with a documented reason",
        failures.len()
    );
}

/// The quality factors a user meets, from a lever in liquid (Q = 30 on every mode) to one in
/// vacuum (3000): each converges to a stable period-1 orbit within the default budget or
/// says why, on the default lever. CI runs two points (Q 30 in light tapping with adhesion,
/// Q 3000 in hard tapping without); `FTAFM_ORBIT_GRID=full` runs Q = 30, 100, 1000 and
/// 3000 at set-point ratios 0.3, 0.6 and 0.9, adhesion off and on (24 points; all converge,
/// 0.5–17 s each on a 2-vCPU Xeon beside other work, 2.0 min in all).
#[test]
fn quality_factors_from_30_to_3000_converge_or_say_why() {
    let full = std::env::var("FTAFM_ORBIT_GRID").is_ok_and(|v| v == "full");
    let mut grid = Vec::new();
    for q in [30.0, 100.0, 1000.0, 3000.0] {
        for ratio in [0.3, 0.6, 0.9] {
            for adhesion in [false, true] {
                let ci = (q, ratio, adhesion) == (30.0, 0.9, true)
                    || (q, ratio, adhesion) == (3000.0, 0.3, false);
                if full || ci {
                    grid.push((q, ratio, adhesion));
                }
            }
        }
    }
    let mut failures = Vec::new();
    for (q, ratio, adhesion) in grid {
        let lever: (f64, f64, &[f64], f64) = (100e3, 20.0, &[q; 5], 10e-9);
        let s = settings(lever, 129e9, 20e-9, ratio, adhesion);
        let what = format!("Q {q} on every mode, ratio {ratio}, adhesion {adhesion}");
        failures.extend(attempt(&s, &what).err());
    }
    assert_documented(&failures);
}
