//! The live PID units (`/pids/N/*`) in the synthesiser: an amplitude loop on the surface
//! distance settles where the physics puts that amplitude, its output limits hold and its
//! integrator does not wind up, enabling, disabling and retuning while it runs are
//! bumpless, the same seed gives the same loop trace, and the settings checks refuse bad
//! gains and conflicting outputs naming the node. The daemon reports each unit's update in
//! `status`, stamped with its epoch.

mod common;

use common::loops::{change, mean, refused, run, start};
use ftafm::config::{PidInput, Settings, default_settings};
use ftafm::synth::{PidReading, SynthPlan};
use serde_json::json;

/// The default (coupled engine, every noise source on) with PID 0 an amplitude loop on the
/// surface distance at harmonic 1, holding `setpoint` (m).
fn amplitude_loop(setpoint: f64) -> Settings {
    let mut s = default_settings();
    let pid = &mut s.pids[0];
    pid.enable = true;
    pid.input = PidInput::R;
    pid.harmonic = 1;
    pid.setpoint = setpoint;
    pid.p = 0.0;
    pid.i = 1200.0;
    pid.output_min = 0.0;
    pid.output_max = 100e-9;
    s
}

/// The steady photodiode amplitude at harmonic 1 (m, peak) with the surface at
/// `distance`: the coupled engine's own periodic orbit, as the scan's auto set-point takes
/// it (no loop involved).
fn amplitude_at(distance: f64) -> f64 {
    let mut s = default_settings();
    s.surface.distance = distance;
    s.scan.enable = true;
    SynthPlan::new(&s).unwrap().scan.unwrap().setpoint
}

#[test]
fn an_amplitude_loop_on_the_surface_distance_settles_where_the_physics_puts_its_setpoint() {
    // The set-point is the amplitude the orbit has with the surface at 18 nm; the loop
    // starts from /surface/distance = 20 nm and must find 18 nm.
    let target = 18e-9;
    let setpoint = amplitude_at(target);
    let (plan, mut state, mut rt) = start(&amplitude_loop(setpoint), 3);
    let period = 1.0 / plan.drive_frequency;
    let readings = run(&plan, &mut state, &mut rt, 0.03);
    assert!(readings.iter().all(|r| r.unit == 0));
    // One update per drive period.
    let expected = 0.03 / period;
    assert!(
        (readings.len() as f64 - expected).abs() <= 2.0,
        "{} updates in 30 ms, {expected} periods",
        readings.len()
    );
    for pair in readings.windows(2) {
        let gap = pair[1].sample - pair[0].sample;
        assert!(
            (gap as f64 - period * plan.sample_rate).abs() <= 1.0,
            "updates {gap} samples apart"
        );
    }
    // The last 10 ms: the surface where the physics has that amplitude.
    let tail: Vec<&PidReading> = readings
        .iter()
        .filter(|r| r.sample as f64 / plan.sample_rate > 0.02)
        .collect();
    let distance = mean(tail.iter().map(|r| r.output));
    let amplitude = mean(tail.iter().map(|r| r.measurement));
    let spread = tail
        .iter()
        .map(|r| (r.output - distance).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "set-point {setpoint:e} m (the orbit's at 18 nm): the loop holds {:.4} nm (± {:.4} nm), \
         reads {amplitude:e} m",
        distance * 1e9,
        spread * 1e9
    );
    assert!(
        (distance - target).abs() < 0.1e-9,
        "settled at {distance:e} m, the physics says {target:e} m"
    );
    assert!(
        (amplitude - setpoint).abs() / setpoint < 2e-3,
        "reads {amplitude:e} against the set-point {setpoint:e}"
    );
    assert!(tail.iter().all(|r| !r.limited));
    // The surface the engine integrates is where the loop put it.
    assert_eq!(rt.distance(), readings.last().unwrap().output);
}

#[test]
fn an_unreachable_setpoint_pins_the_output_at_its_limit_and_the_loop_recovers_at_once() {
    // No distance gives more than the free amplitude: the loop pulls the surface away
    // until output_max holds it.
    let reachable = amplitude_at(18e-9);
    let free = amplitude_at(60e-9);
    let mut settings = amplitude_loop(1.2 * free);
    settings.pids[0].output_max = 40e-9;
    let (mut plan, mut state, mut rt) = start(&settings, 4);
    let pinned = run(&plan, &mut state, &mut rt, 0.02);
    assert!(
        pinned.iter().all(|r| (0.0..=40e-9).contains(&r.output)),
        "the output leaves [0, 40 nm]"
    );
    let last = pinned.last().unwrap();
    assert_eq!(last.output, 40e-9, "pinned at output_max");
    assert!(last.limited, "reported at its limit");
    let at_limit = pinned.iter().filter(|r| r.limited).count();
    assert!(
        at_limit > pinned.len() / 2,
        "{at_limit} of {} updates at the limit",
        pinned.len()
    );

    // Back to a reachable set-point: with the integrator held at the limit (conditional
    // integration) the output leaves it on the next update; a wound-up integrator (some
    // 15 ms of a 20 % error at I = 1200/s: 0.1 µm past the limit) would hold it there for
    // milliseconds.
    settings.pids[0].setpoint = reachable;
    change(&mut plan, &mut state, &mut rt, &settings);
    let recovery = run(&plan, &mut state, &mut rt, 0.02);
    let left = recovery.iter().position(|r| r.output < 40e-9).unwrap();
    assert!(left <= 1, "left the limit after {left} updates");
    let t0 = recovery[0].sample;
    let settled = recovery
        .iter()
        .rposition(|r| (r.output - 18e-9).abs() > 0.2e-9)
        .map_or(0.0, |i| (recovery[i].sample - t0) as f64 / plan.sample_rate);
    eprintln!(
        "pinned at 40 nm for 20 ms ({at_limit} updates limited), then left the limit after \
         {left} update(s) and settled within 0.2 nm of 18 nm after {:.2} ms",
        settled * 1e3
    );
    assert!(settled < 8e-3, "settled after {settled} s");
}

#[test]
fn enabling_disabling_and_retuning_while_running_are_bumpless() {
    let setpoint = amplitude_at(18e-9);
    let mut settings = amplitude_loop(setpoint);
    let (mut plan, mut state, mut rt) = start(&settings, 5);
    let before = run(&plan, &mut state, &mut rt, 0.015);
    let held = before.last().unwrap().output;
    assert!((held - 18e-9).abs() < 0.3e-9, "{held}");

    // Disabled: no more updates, the surface stays where the loop left it.
    settings.pids[0].enable = false;
    change(&mut plan, &mut state, &mut rt, &settings);
    assert!(rt.active(&plan), "the held surface keeps the loops' path");
    assert!(run(&plan, &mut state, &mut rt, 0.002).is_empty());
    assert_eq!(rt.distance(), held);

    // Enabled again: the first output is the surface's present value, exactly.
    settings.pids[0].enable = true;
    change(&mut plan, &mut state, &mut rt, &settings);
    let again = run(&plan, &mut state, &mut rt, 0.005);
    assert_eq!(again[0].output, held, "bumpless enable");
    let last = again.last().unwrap().output;

    // New gains: the integrator keeps its sum, so the output continues from where it was
    // (a fresh controller would restart from /surface/distance = 20 nm).
    settings.pids[0].i = 2400.0;
    settings.pids[0].p = 0.05;
    change(&mut plan, &mut state, &mut rt, &settings);
    let retuned = run(&plan, &mut state, &mut rt, 0.01);
    let jump = (retuned[0].output - last).abs();
    eprintln!(
        "held {:.4} nm while disabled; re-enabled at exactly it; new gains moved the output by \
         {:.2e} nm on their first update",
        held * 1e9,
        jump * 1e9
    );
    assert!(jump < 0.05e-9, "jump {jump:e} m on a change of gains");
    let end = retuned.last().unwrap().output;
    assert!((end - 18e-9).abs() < 0.3e-9, "still holds: {end}");

    // A new /surface/distance with the loop off moves the surface there.
    settings.pids[0].enable = false;
    settings.surface.distance = 22e-9;
    change(&mut plan, &mut state, &mut rt, &settings);
    assert_eq!(rt.distance(), 22e-9);
    assert!(!rt.active(&plan), "nothing held: the plain path again");
}

#[test]
fn the_same_seed_and_settings_give_the_same_loop_trace() {
    let settings = amplitude_loop(amplitude_at(19e-9));
    let trace = |seed: u64| {
        let (plan, mut state, mut rt) = start(&settings, seed);
        run(&plan, &mut state, &mut rt, 0.005)
            .iter()
            .map(|r| (r.sample, r.output.to_bits(), r.measurement.to_bits()))
            .collect::<Vec<_>>()
    };
    let a = trace(11);
    assert!(a.len() > 400);
    assert_eq!(a, trace(11), "same seed, same trace, bit for bit");
    // The noise reaches the loop: another seed, another trace.
    assert_ne!(a, trace(12));
}

/// A unit's demodulator reads a harmonic's phase as the lock-in bank does: zero gains (it
/// measures, the output stays), the phase at harmonic 2 against the bank's on the same
/// samples. Without the ADC's filter, so that the bank's reference (phase 0 at its first
/// sample) is the synthesis's; with it, both take its delay off alike (`output_phase`).
#[test]
fn the_phase_input_reads_as_the_lock_in_does() {
    use ftafm::dsp::{Demodulator, LockInBank};
    let mut settings = amplitude_loop(0.0);
    settings.noise.enable = false;
    settings.synth.anti_alias = false;
    let pid = &mut settings.pids[0];
    (pid.input, pid.harmonic, pid.p, pid.i) = (PidInput::Phase, 2, 0.0, 0.0);
    let (plan, mut state, mut rt) = start(&settings, 1);
    let mut bank = LockInBank::new(
        plan.sample_rate,
        plan.drive_frequency,
        &[Demodulator::new(2, 4, 1e-4, 1e4)],
    )
    .unwrap();
    let mut block = vec![0.0; 4096];
    let (mut readings, mut lock_in) = (Vec::new(), None);
    for _ in 0..50 {
        plan.process_pids(
            &mut state,
            &mut rt,
            &mut block,
            &mut |r| readings.push(r),
            &mut |_| {},
        );
        bank.process(&block, |s| lock_in = Some(s));
    }
    let lock_in = lock_in.unwrap();
    let last = readings.last().unwrap();
    let wrapped = |d: f64| {
        (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
    };
    let difference = wrapped(last.measurement - lock_in.phase());
    eprintln!(
        "harmonic 2: the PID reads {:.6} rad, the lock-in {:.6} rad (r = {:e} m)",
        last.measurement,
        lock_in.phase(),
        lock_in.r()
    );
    assert!(difference.abs() < 1e-3, "{difference} rad apart");
    // Zero gains: the surface stays where it was.
    assert!(readings.iter().all(|r| r.output == 20e-9));
}

/// A file names only the units and keys it changes; a whole file written before the PIDs
/// existed (no `[pids]`) has the four at their defaults; a unit past 3 is an unknown key.
#[test]
fn files_set_the_units_by_index() {
    let s = ftafm::config::load_str(
        "[pids.2]\nenable = true\nsetpoint = 18e-9\ninput = \"x\"\n",
        "site.toml",
    )
    .unwrap();
    assert!(s.pids[2].enable && s.pids[2].input == PidInput::X);
    assert_eq!(s.pids[2].setpoint, 18e-9);
    assert_eq!(s.pids[2].i, 1200.0, "the rest from the default");
    assert!(!s.pids[0].enable);

    let default = ftafm::config::DEFAULT_TOML;
    let at = default.find("\n[pids]").unwrap();
    let before_pids = &default[..at];
    let old: Settings = toml::from_str(before_pids).unwrap();
    assert_eq!(old.pids, default_settings().pids);

    let e = ftafm::config::load_str("[pids.4]\nenable = true\n", "site.toml").unwrap_err();
    assert!(e.to_string().contains("0 … 3"), "{e}");
}

/// A change refused: the nodes set, the node the error names, words its message has.
type Case<'a> = (&'a [(&'a str, serde_json::Value)], &'a str, &'a [&'a str]);

#[test]
fn bad_gains_and_limits_are_refused_naming_the_node_and_the_range() {
    let s = default_settings();
    let on = ("/pids/2/enable", json!(true));
    let cases: [Case; 6] = [
        // The node's own range.
        (
            &[("/pids/2/p", json!(2e9))],
            "/pids/2/p",
            &["1e9", "/pids/2/p"],
        ),
        // An integral gain against the proportional's sign.
        (
            &[
                on.clone(),
                ("/pids/2/p", json!(0.1)),
                ("/pids/2/i", json!(-5.0)),
            ],
            "/pids/2/i",
            &["≥ 0", "allowed"],
        ),
        // The derivative's bandwidth above the PID's Nyquist frequency (half the drive's).
        (
            &[on.clone(), ("/pids/2/d_bandwidth", json!(60e3))],
            "/pids/2/d_bandwidth",
            &["50000", "Nyquist"],
        ),
        (
            &[
                on.clone(),
                ("/pids/2/output_min", json!(50e-9)),
                ("/pids/2/output_max", json!(40e-9)),
            ],
            "/pids/2/output_min",
            &["output_max"],
        ),
        // The surface distance's own range.
        (
            &[on.clone(), ("/pids/2/output_max", json!(2e-6))],
            "/pids/2/output_max",
            &["1 µm", "surface"],
        ),
        (
            &[on.clone(), ("/pids/2/harmonic", json!(60))],
            "/pids/2/harmonic",
            &["out of band", "49"],
        ),
    ];
    for (changes, path, words) in cases {
        let e = refused(&s, changes);
        let text = e.to_string();
        eprintln!("{path}: {text}");
        assert_eq!(e.path(), path, "{text}");
        assert!(text.contains(path), "{text}");
        for w in words {
            assert!(text.contains(w), "{w:?} in {text}");
        }
    }
    // A reverse-acting loop (every gain negative) is fine.
    let mut ok = s.clone();
    ok.set_many(&[
        ("/pids/2/enable".into(), json!(true)),
        ("/pids/2/p".into(), json!(-0.1)),
        ("/pids/2/i".into(), json!(-100.0)),
    ])
    .unwrap();
    ftafm::model::check(&ok).unwrap();
}

#[test]
fn conflicting_outputs_are_refused_naming_both_sides() {
    let s = amplitude_loop(20e-9);
    let cases: [Case; 4] = [
        (
            &[("/pids/1/enable", json!(true))],
            "/pids/1/output",
            &["/pids/0", "at most one enabled PID"],
        ),
        (
            &[("/scan/enable", json!(true))],
            "/pids/0/output",
            &["/scan/enable", "/feedback/enable"],
        ),
        (
            &[("/synth/engine", json!("paper"))],
            "/pids/0/output",
            &["/synth/engine", "coupled"],
        ),
        (
            &[
                ("/sweeper/parameter", json!("/surface/distance")),
                ("/sweeper/start", json!(10e-9)),
                ("/sweeper/stop", json!(30e-9)),
                ("/sweeper/enable", json!(true)),
            ],
            "/pids/0/output",
            &["/sweeper/parameter"],
        ),
    ];
    for (changes, path, words) in cases {
        let e = refused(&s, changes);
        let text = e.to_string();
        eprintln!("{path}: {text}");
        assert_eq!(e.path(), path, "{text}");
        for w in words {
            assert!(text.contains(w), "{w:?} in {text}");
        }
    }
    // Another output … of which there is one today: two PIDs, one enabled, are fine.
    let mut two = s.clone();
    two.set("/pids/3/setpoint", &json!(1e-9)).unwrap();
    ftafm::model::check(&two).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_reports_each_units_update_under_the_epoch_it_ran() {
    let daemon = common::Daemon::start(common::light()).await;
    let mut ws = common::connect(daemon.addr).await;
    let setpoint = amplitude_at(19e-9);
    let reply = common::call(
        &mut ws,
        json!({"op": "set", "values": {
            "/pids/0/setpoint": setpoint,
            "/pids/0/enable": true,
        }}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    let epoch = reply["epoch"].as_u64().expect("set replies with its epoch");
    // A bad gain is refused over the socket, naming the node.
    let bad = common::call(
        &mut ws,
        json!({"op": "set", "path": "/pids/0/d_bandwidth", "value": 60e3}),
    )
    .await;
    assert_eq!(common::code(&bad), "invalid_value", "{bad}");
    assert!(bad.to_string().contains("/pids/0/d_bandwidth"), "{bad}");
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "status"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    let status = common::first_of(&mut ws, "status", |s| {
        s["pids"][0]["latest"]["epoch"]
            .as_u64()
            .is_some_and(|e| e >= epoch)
    })
    .await;
    let unit = &status["pids"][0];
    eprintln!("status: {unit}");
    assert_eq!(unit["enable"], true);
    assert_eq!(unit["input"], "r");
    assert_eq!(unit["output"], "surface_distance");
    let latest = &unit["latest"];
    let output = latest["output"].as_f64().unwrap();
    assert!((0.0..=100e-9).contains(&output), "{latest}");
    assert!(latest["updates"].as_u64().unwrap() > 0);
    assert!(latest["error"].as_f64().unwrap().is_finite());
    assert!(status["pids"][1]["latest"].is_null());
    daemon.shutdown().await;
}

/// The `pids` stream: every update of every unit, in columns, none skipped (each unit's
/// updates a drive period apart, `dropped` 0), stamped with the epoch it ran under, and
/// equal to what the synthesiser-level runtime computes (measurement − set-point = −error).
/// Each message's `t_synth_ns` is the Unix time its newest update was synthesised at:
/// after the test began, before the message arrived, and never going back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_pids_stream_carries_every_update() {
    let unix_ns = || {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as u64
    };
    let began = unix_ns();
    let settings = common::light();
    let rate = settings.synth.sample_rate;
    let period = rate / settings.drive.frequency;
    let daemon = common::Daemon::start(settings).await;
    let mut ws = common::connect(daemon.addr).await;
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "pids"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    let setpoint = amplitude_at(19e-9);
    let reply = common::call(
        &mut ws,
        json!({"op": "set", "values": {"/pids/0/setpoint": setpoint, "/pids/0/enable": true}}),
    )
    .await;
    assert_eq!(reply["ok"], true, "{reply}");
    let epoch = reply["epoch"].as_u64().unwrap();
    let mut samples: Vec<u64> = Vec::new();
    let mut synthesised = began;
    while samples.len() < 2000 {
        let m = common::first_of(&mut ws, "pids", |_| true).await;
        let arrived = unix_ns();
        let t_synth_ns = m["t_synth_ns"].as_u64().unwrap();
        assert!(
            (synthesised..=arrived).contains(&t_synth_ns),
            "t_synth_ns {t_synth_ns}: not between the previous message's (or the test's \
             start) {synthesised} and its arrival {arrived}"
        );
        synthesised = t_synth_ns;
        if samples.is_empty() {
            eprintln!(
                "a pids message: seq {}, t {}, t_synth_ns {}, {} updates, first: sample {} \
                 output {} error {}",
                m["seq"],
                m["t"],
                m["t_synth_ns"],
                m["unit"].as_array().unwrap().len(),
                m["sample"][0],
                m["output"][0],
                m["error"][0]
            );
        }
        assert_eq!(m["dropped"], 0, "nothing dropped: {m}");
        let n = m["unit"].as_array().unwrap().len();
        assert!(n > 0);
        for key in [
            "sample",
            "epoch",
            "measurement",
            "error",
            "output",
            "limited",
            "locked",
        ] {
            assert_eq!(m[key].as_array().unwrap().len(), n, "{key}");
        }
        for i in 0..n {
            assert_eq!(m["unit"][i], 0);
            assert_eq!(m["epoch"][i], epoch);
            assert!(m["locked"][i].is_null(), "no PLL");
            let (measured, error) = (
                m["measurement"][i].as_f64().unwrap(),
                m["error"][i].as_f64().unwrap(),
            );
            assert!(
                (setpoint - measured - error).abs() < 1e-18,
                "{measured} {error}"
            );
            samples.push(m["sample"][i].as_u64().unwrap());
        }
        let last = *samples.last().unwrap();
        assert!((m["t"].as_f64().unwrap() - last as f64 / rate).abs() < 1e-12);
    }
    // Every update, one a drive period.
    for pair in samples.windows(2) {
        let gap = (pair[1] - pair[0]) as f64;
        assert!((gap - period).abs() <= 1.0, "updates {gap} samples apart");
    }
    daemon.shutdown().await;
}
