//! The second excitation (`/drive2/*`): bimodal AFM on the coupled engine. Without the
//! surface the lever is linear, so the second excitation adds exactly its own steady tone;
//! tapping under the first, the second mode's response at f2 feels the contact's mean
//! stiffness along the first mode's orbit (first-order averaging), which the engine's own
//! force trace gives independently; and the bimodal AM-FM expressions turn that response
//! and the first mode's amplitude and phase into the sample's modulus.

mod common;

use std::f64::consts::PI;

use ftafm::config::{Settings, default_settings};
use ftafm::physics::bimodal::{self, BimodalEstimate, BimodalLever, BimodalReading};
use ftafm::synth::{SynthPlan, SynthState};
use ftafm::timebase::phase_to_radians;
use rustfft::num_complex::Complex64;

/// Samples the stream settles for (10 ms at 10 MS/s: 30 time constants of mode 1, 45 of
/// mode 2), then is measured for.
const SETTLE: usize = 100_000;
const MEASURE: usize = 200_000;

/// The default lever, noise off, `/drive2` at the lever's own second resonance with a free
/// amplitude `a2` (m), or off where `a2` is 0; the surface at `distance` (m).
fn bimodal(distance: f64, a2: f64) -> Settings {
    let mut s = default_settings();
    s.noise.enable = false;
    s.surface.distance = distance;
    let lever = ftafm::model::cantilever(&s).unwrap();
    s.drive2.frequency = lever.modes[1].frequency;
    s.drive2.enable = a2 > 0.0;
    s.drive2.free_amplitude = if a2 > 0.0 { a2 } else { 1e-9 };
    s
}

/// The samples after `SETTLE`, `MEASURE` of them.
fn stream(settings: &Settings) -> (SynthPlan, Vec<f64>) {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut skip = vec![0.0; SETTLE];
    plan.process(&mut state, &mut skip);
    let mut out = vec![0.0; MEASURE];
    plan.process(&mut state, &mut out);
    (plan, out)
}

/// The complex amplitude X + iY (peak) of `x`'s component at `word` phase words per sample,
/// against the phase the oscillator has at each absolute sample index (0 at sample 0,
/// the cosine's peak), through a Hann window: a tone exactly at the frequency reads
/// exactly, tones ≥ 100 kHz away leak below 1e-9 of their amplitude.
fn demod(x: &[f64], word: u64) -> Complex64 {
    let n = x.len();
    let (mut sum, mut weight) = (Complex64::new(0.0, 0.0), 0.0);
    for (i, &v) in x.iter().enumerate() {
        let w = 0.5 - 0.5 * (2.0 * PI * i as f64 / n as f64).cos();
        let theta = phase_to_radians(word.wrapping_mul((SETTLE + i) as u64));
        sum += Complex64::from_polar(w * v, -theta);
        weight += w;
    }
    sum * (2.0 / weight)
}

/// Without the surface the second excitation adds a pure tone at f2, the steady response
/// the lever's modes give its base motion, on the first's stream: the difference of the
/// streams with and without it, less that tone, is below 1e-9 of it.
#[test]
fn free_second_excitation_adds_its_own_tone() {
    let (plan, both) = stream(&bimodal(1e-6, 1e-9));
    let (_, one) = stream(&bimodal(1e-6, 0.0));
    let word = plan.frequency_word2;
    let d: Vec<f64> = both.iter().zip(&one).map(|(a, b)| a - b).collect();
    let tone = demod(&d, word);
    // The photodiode's steady response to the second excitation, through the ADC's front
    // end (its gain, and its delay of 21.5 samples).
    let f = word as f64 / 2f64.powi(64);
    let drive2 = plan.drive2.expect("the second excitation drives");
    let delay = ftafm::synth::adc::DELAY_HALF_SAMPLES as f64 / 2.0;
    let expected =
        drive2.signal * plan.front_end_gain(f) * Complex64::from_polar(1.0, -2.0 * PI * f * delay);
    assert!(
        (tone - expected).norm() < 1e-6 * expected.norm(),
        "{tone} against {expected}"
    );
    // The tone's photodiode amplitude is mode 2's light-lever factor times the 1 nm tip
    // amplitude, within the other modes' off-resonant share.
    let factor = plan.cantilever.modes[1].light_lever_factor().abs();
    assert!(
        (drive2.signal.norm() / (1e-9 * factor) - 1.0).abs() < 0.01,
        "{} against {factor} nm",
        drive2.signal.norm() / 1e-9
    );
    let mut worst: f64 = 0.0;
    for (i, &v) in d.iter().enumerate() {
        let theta = phase_to_radians(word.wrapping_mul((SETTLE + i) as u64));
        worst = worst.max((v - (tone * Complex64::from_polar(1.0, theta)).re).abs());
    }
    assert!(
        worst < 1e-9 * tone.norm(),
        "residual {worst:e} of {}",
        tone.norm()
    );
}

/// The contact's mean stiffness ⟨k_ts⟩ (N/m) along the first excitation's orbit, from the
/// engine's force at every sub-step: k_ts = dF/dδ = (3/2)·κ^{2/3}·F^{1/3} for Hertz's
/// F = κδ^{3/2}, with κ = (4/3)E*√R from the materials.
fn mean_contact_stiffness(settings: &Settings) -> f64 {
    let plan = SynthPlan::new(settings).unwrap();
    let mut state = SynthState::steady(&plan, 1);
    let mut skip = vec![0.0; SETTLE];
    plan.process(&mut state, &mut skip);
    let trace = plan.coupled_trace(&mut state, 20_000).unwrap();
    let kappa = (4.0 / 3.0) * reduced_modulus(settings) * settings.cantilever.tip_radius.sqrt();
    let sum: f64 = trace
        .force
        .iter()
        .map(|&f| 1.5 * kappa.powf(2.0 / 3.0) * f.max(0.0).cbrt())
        .sum();
    sum / trace.force.len() as f64
}

/// E* (Pa): 1/E* = (1 − ν_t²)/E_t + (1 − ν_s²)/E_s.
fn reduced_modulus(s: &Settings) -> f64 {
    let (t, m) = (&s.tip, &s.sample);
    1.0 / ((1.0 - t.poisson * t.poisson) / t.youngs_modulus
        + (1.0 - m.poisson * m.poisson) / m.youngs_modulus)
}

/// The lever's linear response at `omega` (rad/s) to a point force at the tip: the tip's
/// compliance Σ Hn/k_n and the photodiode's Σ λn·Hn/k_n (m/N, k_n tip-referred, λn the
/// light-lever factor).
fn compliances(plan: &SynthPlan, omega: f64) -> (Complex64, Complex64) {
    let mut tip = Complex64::new(0.0, 0.0);
    let mut photodiode = Complex64::new(0.0, 0.0);
    for m in &plan.cantilever.modes {
        let h = m.transfer(omega) / m.tip_stiffness();
        tip += h;
        photodiode += h * m.light_lever_factor();
    }
    (tip, photodiode)
}

/// What the second mode reads at f2 while the first taps: its response with and without
/// the surface, R = S/S_free, and the linear model of a spring k_ts at the tip:
/// z = z⁰/(1 + k_ts·H_tip), S = S⁰ − k_ts·H_pd·z.
struct SecondMode {
    /// Measured S/S⁰ at f2.
    ratio: Complex64,
    /// The model's S/S⁰ for a spring `k` (N/m).
    model: Box<dyn Fn(f64) -> Complex64>,
    /// The spring (N/m) the model needs for the measured ratio (complex: its imaginary part
    /// is the contact's loss at f2).
    spring: Complex64,
}

fn second_mode(settings: &Settings) -> SecondMode {
    let mut free = settings.clone();
    free.surface.distance = 1e-6;
    let mut one = settings.clone();
    one.drive2.enable = false;
    let mut one_free = free.clone();
    one_free.drive2.enable = false;
    let (plan, tapping) = stream(settings);
    let word = plan.frequency_word2;
    let tone = |a: &[f64], b: &[f64]| {
        let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
        demod(&d, word)
    };
    let contact = tone(&tapping, &stream(&one).1);
    let far = tone(&stream(&free).1, &stream(&one_free).1);
    let drive2 = plan.drive2.unwrap();
    let modes = &plan.cantilever.modes;
    let zeta = drive2.free_tip(modes) / drive2.signal;
    let (h_tip, h_pd) = compliances(&plan, drive2.omega());
    let (a, b) = (h_pd * zeta, h_tip);
    let ratio = contact / far;
    // R = 1 − k·a/(1 + k·b)  ⇔  k = (1 − R)/(a − (1 − R)·b).
    let spring = (1.0 - ratio) / (a - (1.0 - ratio) * b);
    SecondMode {
        ratio,
        model: Box::new(move |k| 1.0 - k * a / (1.0 + k * b)),
        spring,
    }
}

/// Tapping silicon at the defaults (A_set 20 nm of 30 nm) with a 0.5 nm second excitation
/// at f2: the second mode's response moves as a spring ⟨k_ts⟩ at the tip predicts, ⟨k_ts⟩
/// the Hertz contact's mean stiffness over the first mode's orbit from the engine's own
/// force trace. The prediction is first-order averaging; the pulse's harmonics mix f2 with
/// f2 ± k·f1, off the second resonance, a correction of a few per cent.
#[test]
fn second_mode_feels_the_mean_contact_stiffness() {
    for modulus in [1e9, 129e9] {
        let mut s = bimodal(20e-9, 0.5e-9);
        s.sample.youngs_modulus = modulus;
        let mean = {
            let mut one = s.clone();
            one.drive2.enable = false;
            mean_contact_stiffness(&one)
        };
        let m = second_mode(&s);
        let predicted = (m.model)(mean);
        println!(
            "E = {modulus:e}: <k_ts> = {mean:.3} N/m, second mode reads k = {:.3} {:+.3}i N/m; \
             S/S0 {:.4} at {:+.2} deg, predicted {:.4} at {:+.2} deg",
            m.spring.re,
            m.spring.im,
            m.ratio.norm(),
            m.ratio.arg().to_degrees(),
            predicted.norm(),
            predicted.arg().to_degrees()
        );
        assert!(mean > 0.5, "the orbit taps: <k_ts> = {mean}");
        assert!(
            (m.spring.re / mean - 1.0).abs() < 0.1,
            "E = {modulus:e}: the second mode reads {} N/m against <k_ts> = {mean} N/m",
            m.spring.re
        );
        // A purely elastic contact takes no energy from the second mode.
        assert!(m.spring.im.abs() < 0.1 * mean, "loss {} N/m", m.spring.im);
    }
}

/// The bimodal AM-FM estimate ([`ftafm::physics::bimodal`]) from what an instrument reads
/// at `settings`: the first mode's amplitude A1 and phase lag φ1 against its free A01 (the
/// photodiode's at f1, tapping and far from the surface; φ1 is 90° free, at f1), and the
/// second mode's frequency shift Δf2 = f2·k/(2·k2) for the spring k its response gives
/// ([`SecondMode::spring`], what a PLL on it would read). The estimate, and the configured
/// contact's E*.
fn bimodal_estimate(settings: &Settings) -> (BimodalEstimate, f64) {
    let m = second_mode(settings);
    let mut one = settings.clone();
    one.drive2.enable = false;
    let mut far = one.clone();
    far.surface.distance = 1e-6;
    let (plan, tapping) = stream(&one);
    let word = plan.frequency_word;
    let s1 = demod(&tapping, word);
    let s01 = demod(&stream(&far).1, word);
    let modes = &plan.cantilever.modes;
    let lever = BimodalLever {
        k1: modes[0].tip_stiffness(),
        q1: modes[0].q,
        k2: modes[1].tip_stiffness(),
        f2: plan.frequency_word2 as f64 / 2f64.powi(64) * plan.sample_rate,
        tip_radius: settings.cantilever.tip_radius,
    };
    let a01 = settings.drive.free_amplitude;
    // A phase lead of the tapping lever over the free one is a smaller lag.
    let reading = BimodalReading {
        free_amplitude: a01,
        amplitude: a01 * s1.norm() / s01.norm(),
        phase_lag: PI / 2.0 - (s1 / s01).arg(),
        frequency_shift: lever.f2 * m.spring.re / (2.0 * lever.k2),
    };
    (
        bimodal::estimate(&lever, &reading).unwrap(),
        reduced_modulus(settings),
    )
}

/// The bimodal AM-FM expressions on the coupled engine, tapping at A_set/A01 = 2/3 with a
/// 0.1 nm second excitation at f2, each modulus on a lever matched to it (the softest
/// levers for the softest samples): E* within 10 % of the configured contact's from 1 MPa
/// to 100 GPa. Their error is the expressions' own (a tap short against the swing,
/// first-order averaging of the second mode), not noise: the streams are noiseless.
#[test]
fn bimodal_expressions_give_the_modulus_from_1_mpa_to_100_gpa() {
    for (lever, modulus) in [
        ("ac240", 1e6),
        ("ac240", 10e6),
        ("multi75", 100e6),
        ("tap150", 1e9),
        ("tap300", 10e9),
        ("tap300", 100e9),
        ("tap525", 100e9),
    ] {
        let mut s = ftafm::config::load_with_presets(&[lever.to_owned()], None).unwrap();
        s.noise.enable = false;
        s.sample.youngs_modulus = modulus;
        let model = ftafm::model::cantilever(&s).unwrap();
        s.drive2.frequency = model.modes[1].frequency;
        s.drive2.enable = true;
        s.drive2.free_amplitude = 0.1e-9;
        let (e, truth) = bimodal_estimate(&s);
        let error = e.reduced_modulus / truth - 1.0;
        println!(
            "{lever:8} E = {modulus:8.1e} Pa: E* {:.4e} against {truth:.4e} Pa ({:+.1} %), \
             <F> {:.3} nN, <k_ts> {:.3} N/m, d {:.3} nm; short tap {:+.1} %, d {:.3} nm",
            e.reduced_modulus,
            100.0 * error,
            e.mean_force * 1e9,
            e.mean_stiffness,
            e.indentation * 1e9,
            100.0 * (e.short_tap_modulus / truth - 1.0),
            e.short_tap_indentation * 1e9
        );
        assert!(
            error.abs() < 0.1,
            "{lever}, E = {modulus:e}: {:+.1} %",
            100.0 * error
        );
    }
}

/// Switching the second excitation on while the lever runs (a `set` of `/drive2/enable`):
/// the modes keep their displacement and velocity, so the signal has no step, and the
/// second mode rings up towards its steady tone as 1 − e^{−t/τ2}, τ2 = Q2/(π·f2), driven
/// at its resonance. Free lever, noise off: the difference from the stream without it is
/// the second excitation's response alone.
#[test]
fn second_excitation_switched_on_rings_up_mode_two() {
    let with = bimodal(1e-6, 1e-9);
    let without = bimodal(1e-6, 0.0);
    let (old, new) = (
        SynthPlan::new(&without).unwrap(),
        SynthPlan::new(&with).unwrap(),
    );
    let mut switched = SynthState::steady(&old, 1);
    let mut reference = switched.clone();
    let mut before = vec![0.0; SETTLE];
    old.process(&mut switched, &mut before);
    old.process(&mut reference, &mut before);
    switched.retarget(&old, &new);
    let n = 40_000;
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    new.process(&mut switched, &mut a);
    old.process(&mut reference, &mut b);
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    let steady = new.drive2.unwrap().signal.norm()
        * new.front_end_gain(new.frequency_word2 as f64 / 2f64.powi(64));
    // No step: the first samples after the switch differ by less than the tone moves in
    // one sample.
    let omega_h = 2.0 * PI * new.frequency_word2 as f64 / 2f64.powi(64);
    assert!(d[0].abs() < steady * omega_h, "a step of {:e} m", d[0]);
    let mode = &new.cantilever.modes[1];
    let tau = mode.q / (PI * mode.frequency) * new.sample_rate;
    // The envelope over windows of 1000 samples (the ring-up moves by 0.5 % across one).
    let window = 1000;
    let mut worst: f64 = 0.0;
    for w in (2..n / window).step_by(3) {
        let chunk = &d[w * window..(w + 1) * window];
        let word = new.frequency_word2;
        let mut sum = Complex64::new(0.0, 0.0);
        for (i, &v) in chunk.iter().enumerate() {
            let theta = phase_to_radians(word.wrapping_mul((SETTLE + w * window + i) as u64));
            sum += Complex64::from_polar(v, -theta);
        }
        let envelope = (sum * (2.0 / window as f64)).norm() / steady;
        let t = (w as f64 + 0.5) * window as f64;
        let expected = 1.0 - (-t / tau).exp();
        worst = worst.max((envelope - expected).abs());
    }
    println!("ring-up: worst |envelope − (1 − e^(−t/τ2))| = {worst:.4}, τ2 = {tau:.0} samples");
    assert!(worst < 0.02, "the ring-up departs by {worst}");
}

/// Through the daemon: a demodulator on oscillator "drive2" reads the second excitation's
/// tone as the synthesiser made it (the photodiode's steady response through the ADC's
/// front end, its delay taken out by the reference), while the drive's harmonic 1 beside it
/// reads the first's; the force inversion and the `demods` stream's format are unchanged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_daemon_demodulates_each_excitation_against_its_oscillator() {
    use ftafm::config::Oscillator;
    use serde_json::json;
    let mut settings = common::light();
    settings.noise.enable = false;
    settings.surface.distance = 1e-6;
    let lever = ftafm::model::cantilever(&settings).unwrap();
    settings.drive2.enable = true;
    settings.drive2.frequency = lever.modes[1].frequency;
    settings.drive2.free_amplitude = 1e-9;
    settings.demods[1].oscillator = Oscillator::Drive2;
    settings.demods[1].harmonic = 1;
    let plan = SynthPlan::new(&settings).unwrap();
    let f = |word: u64| word as f64 / 2f64.powi(64);
    let expected1 = plan.drive.signal * plan.front_end_gain(f(plan.frequency_word));
    let expected2 = plan.drive2.unwrap().signal * plan.front_end_gain(f(plan.frequency_word2));
    let daemon = common::Daemon::start(settings.clone()).await;
    let mut ws = common::connect(daemon.addr).await;
    let sub = common::call(&mut ws, json!({"op": "subscribe", "stream": "demods"})).await;
    assert_eq!(sub["ok"], true, "{sub}");
    // 50 ms in: 100 of the demodulators' time constants, 25 of mode 2's.
    let frame = common::first_of(&mut ws, "demods", |m| m["t"].as_f64().unwrap() > 0.05).await;
    let read = |index: u64| {
        let d = frame["demods"]
            .as_array()
            .unwrap()
            .iter()
            .find(|d| d["index"] == index)
            .unwrap();
        assert!(
            d.get("oscillator").is_none(),
            "the stream's format is unchanged: {d}"
        );
        Complex64::new(d["x"].as_f64().unwrap(), d["y"].as_f64().unwrap())
    };
    for (index, expected) in [(0, expected1), (1, expected2)] {
        let got = read(index);
        assert!(
            (got - expected).norm() < 1e-4 * expected.norm(),
            "demodulator {index}: {got} against {expected}"
        );
    }
    daemon.shutdown().await;
}
