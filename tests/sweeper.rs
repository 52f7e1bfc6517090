//! The sweeper over a real WebSocket: a free tune recovers f1 and Q, an approach curve
//! follows the tapping solution, every parameter kind steps and is restored, an abort
//! stops it, bad ranges are refused naming the node.

use serde_json::{Value, json};

mod common;
use common::*;

/// Free-running at 2 MS/s with 1 kHz demodulators: sweeps take well under a second.
fn fast() -> ftafm::config::Settings {
    let mut s = light();
    s.synth.realtime = false;
    for d in &mut s.demods {
        d.rate = 1000.0;
    }
    s
}

/// Starts the sweep `values` describe and returns its point messages and the final one.
async fn sweep(ws: &mut Ws, values: Value) -> (Vec<Value>, Value) {
    let r = call(ws, json!({"op": "subscribe", "stream": "sweep"})).await;
    assert_eq!(r["ok"], true, "{r}");
    let mut values = values;
    values["/sweeper/enable"] = json!(true);
    // Points may come before the reply: they are kept.
    let mut early = Vec::new();
    let r = call_keeping(
        ws,
        json!({"op": "set", "values": values}),
        "sweep",
        &mut early,
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let mut points = Vec::new();
    let mut early = early.into_iter();
    loop {
        // A point may wait for its force estimator (built at nice 10): a hang guard only.
        let m = match early.next() {
            Some(m) => m,
            None => next_within(ws, "sweep", std::time::Duration::from_secs(120)).await,
        };
        if m["done"] == true {
            return (points, m);
        }
        points.push(m);
    }
}

fn h1(point: &Value) -> (f64, f64) {
    let d = point["demods"]
        .as_array()
        .unwrap()
        .iter()
        .find(|d| d["harmonic"] == 1)
        .unwrap();
    (d["r"].as_f64().unwrap(), d["phase"].as_f64().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_free_tune_finds_f1_and_q_and_restores_the_drive() {
    let d = Daemon::start(fast()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/surface/distance": 200e-9, "/sweeper/parameter": "/drive/frequency",
               "/sweeper/start": 99e3, "/sweeper/stop": 101e3, "/sweeper/points": 121}),
    )
    .await;
    assert_eq!(done["outcome"], "done", "{done}");
    assert_eq!(points.len(), 121);
    let tune = &done["tune"];
    let (f0, q) = (tune["f0"].as_f64().unwrap(), tune["q"].as_f64().unwrap());
    println!("tune: {tune}");
    for p in points.iter().step_by(20) {
        println!("{} {:?} {}", p["value"], h1(p), p["free_amplitude"]);
    }
    assert!((f0 / 100e3 - 1.0).abs() < 5e-4, "f0 = {f0}");
    assert!((q / 100.0 - 1.0).abs() < 0.03, "Q = {q}");
    // 200 nm is out of the 30 nm tip's reach: no retract.
    assert_eq!(done["retracted"], Value::Null, "{done}");
    // The phase against the drive crosses −90° at resonance.
    let phase = tune["phase_to_drive_at_f0"].as_f64().unwrap();
    assert!(
        (phase + std::f64::consts::FRAC_PI_2).abs() < 0.05,
        "phase {phase} rad at f0"
    );
    let below = points[0]["h1_phase_to_drive"].as_f64().unwrap();
    let above = points[120]["h1_phase_to_drive"].as_f64().unwrap();
    assert!(
        below > -0.5 && below < 0.0 && above < -2.6,
        "{below} … {above}"
    );
    // Restored: the drive follows f1 again at the free amplitude it had.
    for (path, value) in [
        ("/drive/frequency", json!(100e3)),
        ("/drive/follow_f1", json!(true)),
        ("/drive/free_amplitude", json!(30e-9)),
        ("/sweeper/enable", json!(false)),
    ] {
        let r = call(&mut ws, json!({"op": "get", "path": path})).await;
        assert_eq!(r["value"], value, "{path}");
    }
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tune_at_the_tapping_distance_retracts_the_tip_and_finds_the_free_resonance() {
    // The defaults tap (20 nm from the surface, 30 nm free amplitude): tuned there, the
    // resonance would be the tapping lever's, shifted and broadened. The tune retracts.
    let d = Daemon::start(fast()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/sweeper/parameter": "/drive/frequency",
               "/sweeper/start": 99e3, "/sweeper/stop": 101e3, "/sweeper/points": 61}),
    )
    .await;
    assert_eq!(done["outcome"], "done", "{done}");
    assert_eq!(points.len(), 61);
    let r = &done["retracted"];
    println!("tune: {}, retracted: {r}", done["tune"]);
    assert_eq!(r["from"], 20e-9, "{r}");
    assert_eq!(r["clear"], true, "{r}");
    // Clear of the tip's largest swing (the 30 nm free amplitude at f1) by as much again.
    let distance = r["distance"].as_f64().unwrap();
    assert!((59e-9..=62e-9).contains(&distance), "{r}");
    let tune = &done["tune"];
    let (f0, q) = (tune["f0"].as_f64().unwrap(), tune["q"].as_f64().unwrap());
    assert!((f0 / 100e3 - 1.0).abs() < 5e-4, "f0 = {f0}");
    assert!((q / 100.0 - 1.0).abs() < 0.03, "Q = {q}");
    for (path, value) in [
        ("/surface/distance", json!(20e-9)),
        ("/drive/frequency", json!(100e3)),
        ("/drive/follow_f1", json!(true)),
    ] {
        let r = call(&mut ws, json!({"op": "get", "path": path})).await;
        assert_eq!(r["value"], value, "{path} restored");
    }
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_approach_and_retract_curve_shows_where_contact_starts() {
    let d = Daemon::start(fast()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/sweeper/parameter": "/surface/distance", "/sweeper/start": 40e-9,
               "/sweeper/stop": 8e-9, "/sweeper/points": 33, "/sweeper/direction": "both"}),
    )
    .await;
    assert_eq!(done["outcome"], "done", "{done}");
    assert_eq!(points.len(), 66);
    assert_eq!(points[0]["leg"], "up");
    assert_eq!(points[65]["leg"], "down");
    let approach = &done["approach"];
    println!("{approach}");
    // The free tip (30 nm) first touches where the distance falls below its amplitude.
    for leg in ["contact_up", "contact_down"] {
        let onset = approach[leg].as_f64().unwrap();
        assert!((27e-9..=31e-9).contains(&onset), "{leg} at {onset}");
    }
    // Far out H1 is the free amplitude (times the light lever's 0.918); in contact the
    // tapping amplitude follows the set point, A ≈ A_set.
    let free = h1(&points[0]).0;
    assert!(
        (free / (0.9177 * 30e-9) - 1.0).abs() < 0.02,
        "free H1 {free}"
    );
    for p in &points {
        let dist = p["value"].as_f64().unwrap();
        let (r, _) = h1(p);
        if dist < 25e-9 {
            let ratio = r / free / (dist / 30e-9);
            assert!((ratio - 1.0).abs() < 0.08, "H1 {r} at {dist}: {ratio}");
        }
    }
    // One branch in this model: approach and retract agree, without jumps.
    assert_eq!(approach["jumps"], json!([]), "{approach}");
    let hysteresis = approach["hysteresis"]["max"].as_f64().unwrap();
    assert!(hysteresis < 0.02, "{approach}");
    let r = call(&mut ws, json!({"op": "get", "path": "/surface/distance"})).await;
    assert_eq!(r["value"], 20e-9, "the distance is restored");
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_parameter_kind_steps_and_is_restored() {
    let d = Daemon::start(fast()).await;
    let mut ws = connect(d.addr).await;
    for (path, start, stop, scale, original) in [
        (
            "/drive/free_amplitude",
            25e-9,
            35e-9,
            "linear",
            json!(30e-9),
        ),
        ("/sample/youngs_modulus", 1e9, 100e9, "log", json!(129e9)),
    ] {
        let (points, done) = sweep(
            &mut ws,
            json!({"/sweeper/parameter": path, "/sweeper/start": start, "/sweeper/stop": stop,
                   "/sweeper/points": 5, "/sweeper/scale": scale, "/sweeper/direction": "up"}),
        )
        .await;
        assert_eq!(done["outcome"], "done", "{done}");
        let values: Vec<f64> = points
            .iter()
            .map(|p| p["value"].as_f64().unwrap())
            .collect();
        assert_eq!(values.len(), 5);
        assert_eq!((values[0], values[4]), (start, stop));
        if scale == "log" {
            assert!(
                (values[2] / (start * stop).sqrt() - 1.0).abs() < 1e-12,
                "{values:?}"
            );
        }
        let r = call(&mut ws, json!({"op": "get", "path": path})).await;
        assert_eq!(r["value"], original, "{path} restored");
    }
    // A larger free amplitude taps harder: H1 grows with it, the modulus sweep softens H17.
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sweep_is_aborted_by_turning_it_off_and_still_restores() {
    let mut settings = fast();
    settings.synth.realtime = true; // slow enough to abort half-way
    let d = Daemon::start(settings).await;
    let mut ws = connect(d.addr).await;
    call(&mut ws, json!({"op": "subscribe", "stream": "sweep"})).await;
    let mut early = Vec::new();
    let r = call_keeping(
        &mut ws,
        json!({"op": "set", "values": {"/sweeper/parameter": "/surface/distance",
               "/sweeper/start": 30e-9, "/sweeper/stop": 10e-9, "/sweeper/points": 2000,
               "/sweeper/enable": true}}),
        "sweep",
        &mut early,
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let first = match early.into_iter().next() {
        Some(m) => m,
        None => next_of(&mut ws, "sweep").await,
    };
    assert_eq!(first["point"], 0);
    let r = call(
        &mut ws,
        json!({"op": "set", "path": "/sweeper/enable", "value": false}),
    )
    .await;
    assert_eq!(r["ok"], true, "{r}");
    let done = loop {
        let m = next_of(&mut ws, "sweep").await;
        if m["done"] == true {
            break m;
        }
    };
    assert_eq!(done["outcome"], "aborted", "{done}");
    assert!(done["measured"].as_u64().unwrap() < 2000);
    let r = call(&mut ws, json!({"op": "get", "path": "/surface/distance"})).await;
    assert_eq!(r["value"], 20e-9, "restored after the abort");
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_sweeps_are_refused_naming_the_node() {
    let d = Daemon::start(fast()).await;
    let mut ws = connect(d.addr).await;
    for (values, names) in [
        (
            json!({"/sweeper/parameter": "/surface/distance", "/sweeper/start": -1e-9,
                   "/sweeper/stop": 10e-9}),
            "/sweeper/start",
        ),
        (
            json!({"/sweeper/parameter": "/drive/frequency", "/sweeper/start": 99e3,
                   "/sweeper/stop": 2e6}),
            "/sweeper/stop",
        ),
        (
            json!({"/sweeper/parameter": "/sample/youngs_modulus", "/sweeper/start": 1e9,
                   "/sweeper/stop": 1e9}),
            "/sweeper/stop",
        ),
        (
            json!({"/sweeper/parameter": "/drive/free_amplitude", "/sweeper/start": 0.0,
                   "/sweeper/stop": 1e-8, "/sweeper/scale": "log"}),
            "/sweeper/",
        ),
        // A tune far off resonance would need a free amplitude beyond the node's range at f1.
        (
            json!({"/drive/follow_f1": false, "/drive/frequency": 60e3,
                   "/drive/free_amplitude": 5e-7, "/sweeper/parameter": "/drive/frequency",
                   "/sweeper/start": 60e3, "/sweeper/stop": 120e3}),
            "/sweeper/stop",
        ),
    ] {
        let mut values = values;
        values["/sweeper/enable"] = json!(true);
        let r = call(&mut ws, json!({"op": "set", "values": values})).await;
        assert_eq!(code(&r), "invalid_value", "{r}");
        let message = r["error"]["message"].as_str().unwrap();
        assert!(message.contains(names), "{message}");
        let enabled = call(&mut ws, json!({"op": "get", "path": "/sweeper/enable"})).await;
        assert_eq!(enabled["value"], false);
    }
    let r = call(
        &mut ws,
        json!({"op": "set", "path": "/sweeper/parameter", "value": "/cantilever/k"}),
    )
    .await;
    assert_eq!(code(&r), "invalid_value");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("/surface/distance"),
        "{r}"
    );
    d.shutdown().await;
}

/// The photodiode's H1 (peak, m) on the coupled periodic orbit at `distance`, from the
/// offline solution (physics.md §6): the free response plus the response to the force.
fn coupled_h1(settings: &ftafm::config::Settings, distance: f64) -> f64 {
    use ftafm::physics::spectrum::photodiode_transfer;
    use ftafm::physics::{CoupledProblem, HertzContact};
    let plan = ftafm::synth::SynthPlan::new(settings).unwrap();
    let cantilever = ftafm::model::cantilever(settings).unwrap();
    let orbit = CoupledProblem::new(
        &cantilever,
        plan.drive_frequency,
        settings.drive.free_amplitude,
        distance,
        HertzContact::new(
            ftafm::model::elastic(settings.tip),
            ftafm::model::elastic(settings.sample),
            settings.cantilever.tip_radius,
        ),
    )
    .solve(1)
    .unwrap();
    let omega = 2.0 * std::f64::consts::PI * plan.drive_frequency;
    let tap = photodiode_transfer(&cantilever, omega) * orbit.force_coefficients[1] * 2.0;
    (plan.free_signal() + tap).norm()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_the_coupled_engine_the_approach_follows_the_periodic_orbit() {
    let mut settings = fast();
    settings.synth.engine = ftafm::config::Engine::Coupled;
    let d = Daemon::start(settings.clone()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/sweeper/parameter": "/surface/distance", "/sweeper/start": 40e-9,
               "/sweeper/stop": 8e-9, "/sweeper/points": 17, "/sweeper/direction": "both",
               "/sweeper/averaging": 20}),
    )
    .await;
    assert_eq!(done["outcome"], "done", "{done}");
    let approach = &done["approach"];
    println!("{approach}");
    let mut worst = 0.0f64;
    for p in points.iter().filter(|p| p["leg"] == "up") {
        let dist = p["value"].as_f64().unwrap();
        let (r, _) = h1(p);
        let want = coupled_h1(&settings, dist);
        let err = r / want - 1.0;
        println!(
            "A_set {:.1} nm: H1 {r:.4e} m, orbit {want:.4e} m ({:+.3} %)",
            dist * 1e9,
            err * 100.0
        );
        worst = worst.max(err.abs());
        assert!(err.abs() < 0.01, "H1 {r:e} at {dist:e} m, orbit {want:e} m");
    }
    println!("worst H1 deviation on approach: {:.3} %", worst * 100.0);
    let hysteresis = approach["hysteresis"]["max"].as_f64().unwrap();
    assert!(hysteresis < 0.02, "{approach}");
    d.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_approach_reports_the_force_estimates_and_mean_deflection_of_each_point() {
    // The default chain (10 MS/s, the inversion on), free-running, with demodulator 31
    // measuring the mean (harmonic 0), on the paper engine: the reference is the 1-DOF
    // model, and its estimator builds in 0.1 s. (The coupled engine's takes 1–2 s of CPU at
    // nice 10, which a free-running chain on a busy 2-vCPU machine starves past the point's
    // 60 s wait: docs/ft-afm.md.)
    let mut settings = ftafm::config::default_settings();
    settings.synth.engine = ftafm::config::Engine::Paper;
    settings.synth.realtime = false;
    settings.demods[31].harmonic = 0;
    let d = Daemon::start(settings.clone()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/sweeper/parameter": "/surface/distance", "/sweeper/start": 36e-9,
               "/sweeper/stop": 12e-9, "/sweeper/points": 5, "/sweeper/direction": "up"}),
    )
    .await;
    assert_eq!(done["outcome"], "done", "{done}");
    assert_eq!(points.len(), 5);
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    for p in &points {
        let dist = p["value"].as_f64().unwrap();
        let force = &p["force"];
        println!(
            "{:.0} nm: force {force}, mean {}",
            dist * 1e9,
            p["mean_deflection"]
        );
        let mut s = settings.clone();
        s.surface.distance = dist;
        let model = ftafm::model::impact_oscillator(&s, &cantilever, s.sample)
            .solve()
            .unwrap();
        let mean = p["mean_deflection"]
            .as_f64()
            .expect("demodulator 31 is at harmonic 0");
        if model.in_contact() {
            assert!(force["estimates"].as_u64().unwrap() >= 1, "{force}");
            // The estimate agrees with the 1-DOF force within its own reported uncertainty
            // (4σ) and 2 %.
            let f = force["max_force"].as_f64().unwrap();
            let sigma = force["max_force_sigma"].as_f64().unwrap();
            assert!(sigma > 0.0 && sigma < 0.2 * f, "{force}");
            assert!(
                (f - model.max_force).abs() < 4.0 * sigma + 0.02 * model.max_force,
                "F {f:e} ± {sigma:e} N at {dist:e} m, 1-DOF {:e} N",
                model.max_force
            );
            // The mean tip force is k times the mean deflection (physics.md §5), and the
            // mean of a cut-cosine pulse train is c₀ = 2Fτ/π (Eq. 21): two measurements of
            // one quantity, within the estimates' uncertainty (≈ 3 % each here).
            let tau = force["contact_time_ratio"].as_f64().unwrap();
            let from_pulse = 2.0 * f * tau / std::f64::consts::PI;
            let from_deflection = settings.cantilever.k * mean;
            assert!(
                (from_deflection / from_pulse - 1.0).abs() < 0.15,
                "mean force: k·⟨S⟩ = {from_deflection:e} N, 2Fτ/π = {from_pulse:e} N"
            );
        } else {
            assert_eq!(force["estimates"], 0, "{force}");
            assert!(force["error"].is_string(), "{force}");
            assert!(
                mean.abs() < 5e-12,
                "mean deflection {mean:e} m out of contact"
            );
        }
    }
    d.shutdown().await;
}

/// Where an attractive and a repulsive orbit coexist (the tap300 lever with adhesion at 4 nm,
/// tests/orbit_search.rs), the live approach names the regime of every point as the offline
/// solver names the orbit it is on: each point's H1 is matched to the nearer of the two
/// offline orbits at its distance (the approach's from far and the contact start's), whose
/// branch (the sign of its mean force) the point's regime must be. The approach starts
/// attractive and ends repulsive, and the change is reported as a jump.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_approach_names_the_branch_of_every_point() {
    use ftafm::physics::spectrum::photodiode_transfer;
    use rustfft::num_complex::Complex64;
    let mut settings = fast();
    settings.synth.engine = ftafm::config::Engine::Coupled;
    settings.synth.sample_rate = 6e6;
    settings.cantilever.f1 = 300e3;
    settings.cantilever.k = 40.0;
    settings.cantilever.q = vec![500.0, 2085.0, 1700.0, 1000.0, 130.0];
    settings.cantilever.tip_radius = 8e-9;
    settings.drive.frequency = 300e3;
    settings.drive.free_amplitude = 4e-9;
    settings.surface.distance = 8e-9;
    settings.adhesion.enable = true;
    for d in &mut settings.demods {
        d.harmonic = d.harmonic.min(5);
    }
    let d = Daemon::start(settings.clone()).await;
    let mut ws = connect(d.addr).await;
    let (points, done) = sweep(
        &mut ws,
        json!({"/sweeper/parameter": "/surface/distance", "/sweeper/start": 3.9e-9,
               "/sweeper/stop": 2.3e-9, "/sweeper/points": 5, "/sweeper/direction": "both",
               "/sweeper/averaging": 20}),
    )
    .await;
    // `status` names the live regime too: deep in and far out. The sweeper put the surface
    // back at 8 nm, out of reach; the approach to 2.3 nm retraces the sweep's steps, as a
    // jump from out of reach straight to 2.3 nm can land on either orbit (the drive phase
    // at which the surface arrives decides, and that is the wall clock's).
    let r = call(&mut ws, json!({"op": "subscribe", "stream": "status"})).await;
    assert_eq!(r["ok"], true, "{r}");
    let steps =
        [3.9e-9, 3.5e-9, 3.1e-9, 2.7e-9, 2.3e-9].map(|d| (d, (d == 2.3e-9).then_some("repulsive")));
    for (distance, want) in steps.into_iter().chain([(40e-9, Some("free"))]) {
        let r = call(
            &mut ws,
            json!({"op": "set", "values": {"/surface/distance": distance}}),
        )
        .await;
        assert_eq!(r["ok"], true, "{r}");
        // Settled: 20 ms is 40 of mode 1's and the demodulators' time constants.
        let after = r["t"].as_f64().unwrap() + 0.02;
        let status = first_of(&mut ws, "status", |m| m["t"].as_f64().unwrap() > after).await;
        if let Some(want) = want {
            assert_eq!(status["regime"], want, "at {distance:e} m: {status}");
        }
    }
    d.shutdown().await;
    assert_eq!(done["outcome"], "done", "{done}");
    let approach = &done["approach"];
    println!("{approach}");
    let regimes = approach["regimes"].as_array().unwrap();
    assert_eq!(regimes.len(), points.len(), "{approach}");
    let plan = ftafm::synth::SynthPlan::new(&settings).unwrap();
    let cantilever = ftafm::model::cantilever(&settings).unwrap();
    let omega = 2.0 * std::f64::consts::PI * plan.drive_frequency;
    let gain = plan.front_end_gain(plan.drive_frequency / settings.synth.sample_rate);
    let h1_of = |o: &ftafm::physics::CoupledOrbit| {
        gain * (plan.free_signal()
            + photodiode_transfer(&cantilever, omega) * o.force_coefficients[1] * 2.0)
    };
    // The offline orbits at each distance: the approach's from far, and the repulsive
    // branch traced upwards by continuation from the orbit a tip meeting the surface at the
    // nearest distance settles on, as a retract does.
    let problem_at = |dist: f64| {
        let mut s = settings.clone();
        s.surface.distance = dist;
        ftafm::model::coupled_problem(&s, &cantilever, s.sample, s.drive.frequency)
    };
    let mut distances: Vec<f64> = points
        .iter()
        .map(|p| p["value"].as_f64().unwrap())
        .collect();
    distances.sort_by(f64::total_cmp);
    distances.dedup();
    let mut orbits: Vec<(f64, ftafm::physics::CoupledOrbit)> = Vec::new();
    let mut from: Option<(f64, ftafm::physics::Continuation)> = None;
    for &dist in &distances {
        let problem = problem_at(dist);
        orbits.push((dist, problem.solve(1).unwrap()));
        let traced = match from.take() {
            None => problem
                .solve_from_contact_for_continuation(1, ftafm::physics::SearchLimits::default())
                .ok(),
            // In steps of 0.05 nm: Newton's basin on this branch is narrow.
            Some((last, mut c)) => {
                let steps = ((dist - last) / 0.05e-9).ceil() as usize;
                let mut out = None;
                for i in 1..=steps {
                    let at = last + (dist - last) * i as f64 / steps as f64;
                    match problem_at(at).solve_continued(1, &c) {
                        Ok((o, next)) => {
                            c = next;
                            out = Some((o, c.clone()));
                        }
                        Err(_) => {
                            out = None;
                            break;
                        }
                    }
                }
                out
            }
        };
        from = traced.as_ref().map(|(_, c)| (dist, c.clone()));
        orbits.extend(traced.map(|(o, _)| (dist, o)));
    }
    for (d, o) in &orbits {
        let h = h1_of(o);
        println!(
            "offline {:.2} nm: {:?} θ {:+.2}°, H1 {:.3} nm ∠{:+.3}",
            d * 1e9,
            o.branch,
            o.phase_shift_deg(),
            h.norm() * 1e9,
            h.arg()
        );
    }
    for (p, r) in points.iter().zip(regimes) {
        assert_eq!(r["value"], p["value"]);
        let dist = p["value"].as_f64().unwrap();
        let (amplitude, phase) = h1(p);
        let live = Complex64::from_polar(amplitude, phase);
        let nearest = orbits
            .iter()
            .filter(|(d, _)| *d == dist)
            .map(|(_, o)| o)
            .min_by(|a, b| {
                (h1_of(a) - live)
                    .norm()
                    .total_cmp(&(h1_of(b) - live).norm())
            })
            .unwrap();
        let off = (h1_of(nearest) - live).norm() / live.norm();
        println!(
            "{} {:.2} nm: H1 {:.3} nm ∠{phase:+.3}: {}; nearest orbit {:?} (θ {:+.2}°, {:.2} % off)",
            p["leg"],
            dist * 1e9,
            amplitude * 1e9,
            r["regime"],
            nearest.branch,
            nearest.phase_shift_deg(),
            off * 100.0
        );
        assert!(off < 0.05, "H1 {live} matches no orbit at {dist:e} m");
        assert_eq!(r["regime"], nearest.branch.name(), "{approach}");
    }
    assert_eq!(regimes[0]["regime"], "attractive", "{approach}");
    assert_eq!(regimes[4]["regime"], "repulsive", "{approach}");
    let jump = &approach["jumps"][0];
    assert_eq!(
        (&jump["leg"], &jump["regime_before"], &jump["regime_after"]),
        (&json!("up"), &json!("attractive"), &json!("repulsive")),
        "{approach}"
    );
}
