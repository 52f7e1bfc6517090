//! How well the live FT-AFM inversion tells silicon (129 GPa) from the 10 % softer
//! inhomogeneity (116.1 GPa) with the instrument's default noise, and how well it could.
//!
//! `cargo run --release --example force_noise -- [estimates per material] [method] [averaging]`
//! runs the daemon in-process, collects `force` estimates on each material over the
//! protocol, and prints mean, standard deviation, the mean reported σ, the bias against the
//! value set and the separation |ΔE|/σ_E.
//!
//! `cargo run --release --example force_noise -- crb` prints the Cramér–Rao bound on E for
//! the default configuration: the noise of each harmonic's lock-in reading (thermal motion
//! of every mode through the light lever, detector, ADC, at the demodulators' equivalent
//! noise bandwidth), the Fisher information of ln E from the harmonics (derivatives of each
//! reading with respect to ln E from the 1-DOF model, F, τ and the pulse phase all moving
//! with E at fixed drive and setpoint), and the averaging needed for 3σ.

use std::f64::consts::PI;

use ftafm::config::{Material, Settings};
use ftafm::physics::inversion::{
    ALIAS_HARMONICS, LockInModel, LowPassNoise, NoiseModel, cut_cosine_spectrum,
};
use futures_util::{SinkExt, StreamExt};
use rustfft::num_complex::Complex64;
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Sends `request` and waits for its reply (data messages meanwhile are dropped); panics if
/// it is refused.
async fn send(ws: &mut Ws, request: Value) {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .expect("send");
    loop {
        if let Some(Ok(Message::Text(t))) = ws.next().await {
            let v: Value = serde_json::from_str(&t).expect("JSON");
            match v.get("ok") {
                Some(Value::Bool(true)) => return,
                Some(_) => panic!("{request} refused: {v}"),
                None => {}
            }
        }
    }
}

async fn next_force(ws: &mut Ws) -> Value {
    loop {
        if let Some(Ok(Message::Text(t))) = ws.next().await {
            let v: Value = serde_json::from_str(&t).expect("JSON");
            if v["stream"] == "force" && v.get("ok").is_none() {
                return v;
            }
            if v["ok"] == false {
                panic!("request refused: {v}");
            }
        }
    }
}

fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn stats(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// σ per quadrature of X and Y at harmonic k: ∫ G(kf + Δ)·|H(Δ)|² dΔ over all Δ (the
/// density G is not flat across the filter only at k = 1, on mode 1's resonance).
fn reading_sigma(
    noise: &NoiseModel,
    settings: &Settings,
    cantilever: &ftafm::physics::Cantilever,
    k: usize,
) -> f64 {
    let d = &settings.demods[0];
    let (n, tc) = (d.order as i32, d.timeconstant);
    // Δ = tan(u)/(2πτ): |H|² = cos^{2n}(u), dΔ = du/(2πτ·cos²u).
    let steps = 20_000;
    let mut sum = 0.0;
    for i in 0..steps {
        let u = -0.5 * PI + PI * (i as f64 + 0.5) / steps as f64;
        let delta = u.tan() / (2.0 * PI * tc);
        let f = (k as f64 * settings.drive.frequency + delta).abs();
        sum += noise.density(cantilever, f) * u.cos().powi(2 * n - 2) / (2.0 * PI * tc);
    }
    (sum * PI / steps as f64).sqrt()
}

fn crb() {
    let s = ftafm::config::default_settings();
    let cantilever = ftafm::model::cantilever(&s).expect("cantilever");
    let f = s.drive.frequency;
    let fs = s.synth.sample_rate;
    let noise = NoiseModel {
        temperature: s.noise.temperature,
        detector_density: s.noise.detector_density,
        adc_lsb: 2.0 * s.noise.adc_range / 2f64.powi(s.noise.adc_bits as i32),
        sample_rate: Some(fs),
    };
    let d = &s.demods[0];
    let filter = LowPassNoise {
        order: d.order,
        time_constant: d.timeconstant,
    };
    let period = 1.0 / d.rate;
    let harmonics: Vec<usize> = (1..=32).collect();
    let model = LockInModel::new(&cantilever, f, Some(fs), &harmonics).expect("model");
    println!(
        "noise per reading (X and Y each), order {} τ = {} s, ENBW {:.2} Hz, successive outputs correlated by {:.3}:",
        d.order,
        d.timeconstant,
        filter.bandwidth(),
        filter.correlation(period)
    );
    let sigma: Vec<f64> = harmonics
        .iter()
        .map(|&k| reading_sigma(&noise, &s, &cantilever, k))
        .collect();
    let detector = NoiseModel {
        temperature: 0.0,
        adc_lsb: 0.0,
        ..noise
    };
    let thermal = NoiseModel {
        detector_density: 0.0,
        adc_lsb: 0.0,
        ..noise
    };
    let adc = NoiseModel {
        temperature: 0.0,
        detector_density: 0.0,
        ..noise
    };
    for &k in &[1usize, 2, 3, 6, 12, 17, 18, 27, 32] {
        let at = |m: &NoiseModel| reading_sigma(m, &s, &cantilever, k);
        println!(
            "  H{k:<2}  σ = {:.3} pm  (thermal {:.3} pm, detector {:.3} pm, ADC {:.4} pm)",
            sigma[k - 1] * 1e12,
            at(&thermal) * 1e12,
            at(&detector) * 1e12,
            at(&adc) * 1e12
        );
    }
    let solve = |e: f64| {
        let material = Material {
            youngs_modulus: e,
            poisson: s.sample.poisson,
        };
        ftafm::model::impact_oscillator(&s, &cantilever, material)
            .solve()
            .expect("1-DOF solution")
    };
    // X + iY of every harmonic for the 1-DOF pulse at modulus e (the tap force's part; the
    // drive response at k = 1 does not depend on E).
    let readings = |e: f64| -> Vec<Complex64> {
        let p = solve(e);
        let c = cut_cosine_spectrum(
            p.max_force,
            p.contact_time_ratio,
            p.pulse_phase,
            ALIAS_HARMONICS,
        );
        harmonics
            .iter()
            .map(|&k| 2.0 * model.read(k, |j| c[j]).expect("modelled"))
            .collect()
    };
    let mut need = Vec::new();
    for (name, e0) in [
        ("Si", s.sample.youngs_modulus),
        ("Inh", 0.9 * s.sample.youngs_modulus),
    ] {
        let h = 0.01;
        let (up, down) = (readings(e0 * f64::exp(h)), readings(e0 * f64::exp(-h)));
        let z0 = readings(e0);
        // dZ/dlnE, and dZ/dφ for a free pulse phase (all harmonics shift by e^{−ikδφ}).
        let dx: Vec<Complex64> = up
            .iter()
            .zip(&down)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect();
        let dphi: Vec<Complex64> = z0
            .iter()
            .zip(&harmonics)
            .map(|(z, &k)| z * Complex64::new(0.0, -(k as f64)))
            .collect();
        println!(
            "\n{name} (E = {:.1} GPa): Fisher information of ln E per 1 kHz reading",
            e0 / 1e9
        );
        let info = |kmin: usize, free_phase: bool| -> f64 {
            let (mut ixx, mut ixp, mut ipp) = (0.0, 0.0, 0.0);
            for i in (kmin - 1)..harmonics.len() {
                let w = 1.0 / (sigma[i] * sigma[i]);
                ixx += w * dx[i].norm_sqr();
                ixp += w * (dx[i].conj() * dphi[i]).re;
                ipp += w * dphi[i].norm_sqr();
            }
            if free_phase {
                ixx - ixp * ixp / ipp
            } else {
                ixx
            }
        };
        for (label, kmin, free) in [
            (
                "H2–H32, pulse phase free (what the estimator fits)",
                2,
                true,
            ),
            ("H2–H32, pulse phase from the model", 2, false),
            ("H1–H32, pulse phase free", 1, true),
            ("H1–H32, pulse phase from the model (everything)", 1, false),
        ] {
            let i = info(kmin, free);
            let sigma_e = e0 / i.sqrt();
            println!(
                "  {label:<52} σ_lnE ≥ {:.4}  σ_E ≥ {:6.2} GPa  ΔE/σ_E ≤ {:.2}",
                1.0 / i.sqrt(),
                sigma_e / 1e9,
                0.1 * s.sample.youngs_modulus / sigma_e
            );
        }
        let i = info(2, true);
        let contributions: Vec<String> = (1..harmonics.len())
            .filter_map(|idx| {
                let w = 1.0 / (sigma[idx] * sigma[idx]);
                let share = w * dx[idx].norm_sqr() / info(2, false);
                (share > 0.02).then(|| format!("H{} {:.0} %", idx + 1, 100.0 * share))
            })
            .collect();
        println!(
            "  largest shares (phase from the model): {}",
            contributions.join(", ")
        );
        // Averaging N successive outputs: the variance of the mean of correlated outputs.
        let mut frames = 1;
        let limit = 0.1 * s.sample.youngs_modulus / 3.0;
        while frames < 10_000 {
            let factor = filter.averaged_bandwidth(frames, period) / filter.bandwidth();
            if e0 * (factor / i).sqrt() <= limit {
                break;
            }
            frames += 1;
        }
        println!(
            "  σ_E ≤ ΔE/3 = {:.2} GPa needs the mean of {frames} outputs ({:.1} Hz estimates)",
            limit / 1e9,
            d.rate / frames as f64
        );
        need.push(frames);
    }
    println!(
        "\n3σ (both materials) needs {} averaged outputs: {:.1} estimates per second",
        need.iter().max().unwrap_or(&0),
        d.rate / *need.iter().max().unwrap_or(&1) as f64
    );
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let mut args = std::env::args().skip(1).peekable();
    if args.peek().map(String::as_str) == Some("crb") {
        crb();
        return;
    }
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(2000);
    let method = args.next().unwrap_or_else(|| "full".into());
    let averaging: u32 = args.next().and_then(|a| a.parse().ok()).unwrap_or(1);
    let settings = ftafm::config::default_settings();
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(ftafm::server::run(listener, settings.clone(), async move {
        let _ = stopped.await;
    }));
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
        .await
        .expect("connect");
    send(
        &mut ws,
        json!({"op": "set", "path": "/inversion/method", "value": method}),
    )
    .await;
    send(
        &mut ws,
        json!({"op": "set", "path": "/inversion/averaging", "value": averaging}),
    )
    .await;
    send(&mut ws, json!({"op": "subscribe", "stream": "force"})).await;
    let rate = settings.demods[0].rate / averaging as f64;
    // The estimator is rebuilt off the real-time path after those changes: wait until the
    // estimates come from it (the method's name, and the spacing of `averaging` frames).
    let mut last_t = f64::NEG_INFINITY;
    loop {
        let v = next_force(&mut ws).await;
        let t = v["t"].as_f64().unwrap_or(f64::NAN);
        if v["method"] == method.as_str() && last_t.is_finite() && t - last_t > 0.9 / rate {
            break;
        }
        last_t = t;
    }
    println!(
        "default noise (T = {} K, detector {} m/√Hz, {}-bit ADC), demodulators order {} τ = {} s at {} Hz, method {method}, averaging {averaging} frames ({rate} Hz estimates), {n} estimates per material",
        settings.noise.temperature,
        settings.noise.detector_density,
        settings.noise.adc_bits,
        settings.demods[0].order,
        settings.demods[0].timeconstant,
        settings.demods[0].rate
    );
    let mut results = Vec::new();
    for modulus in [129e9, 116.1e9] {
        send(
            &mut ws,
            json!({"op": "set", "path": "/sample/youngs_modulus", "value": modulus}),
        )
        .await;
        // Skip what was synthesised before the change and 100 ms after it (the modes'
        // transients and the 4th-order filters settle in ≈ 30 ms).
        let settled = unix_ns() + 100_000_000;
        while next_force(&mut ws).await["t_synth_ns"]
            .as_u64()
            .unwrap_or(0)
            < settled
        {}
        let (mut e, mut tau, mut f, mut sigma_e) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut times = Vec::new();
        while e.len() < n {
            let v = next_force(&mut ws).await;
            times.push(v["t"].as_f64().unwrap_or(f64::NAN));
            e.push(v["youngs_modulus"].as_f64().unwrap_or(f64::NAN));
            tau.push(v["contact_time_ratio"].as_f64().unwrap_or(f64::NAN));
            f.push(v["max_force"].as_f64().unwrap_or(f64::NAN));
            sigma_e.push(v["youngs_modulus_sigma"].as_f64().unwrap_or(f64::NAN));
        }
        let mut s = settings.clone();
        s.sample.youngs_modulus = modulus;
        let paper = &ftafm::cli::paper::compute(&s, 1.0)
            .expect("paper")
            .materials[0];
        let (e_mean, e_std) = stats(&e);
        let (t_mean, t_std) = stats(&tau);
        let (f_mean, f_std) = stats(&f);
        let (s_mean, _) = stats(&sigma_e);
        let span = times.last().unwrap_or(&0.0) - times.first().unwrap_or(&0.0);
        println!(
            "E set {:.1} GPa ({n} estimates over {span:.2} s of simulated time): E = {:.2} ± {:.2} GPa (bias {:+.2} %, mean reported σ {:.2} GPa = {:.2} × the spread), τ = {:.5} ± {:.5} ({:+.2} % of paper), F = {:.3} ± {:.3} nN ({:+.2} % of paper)",
            modulus / 1e9,
            e_mean / 1e9,
            e_std / 1e9,
            100.0 * (e_mean / modulus - 1.0),
            s_mean / 1e9,
            s_mean / e_std,
            t_mean,
            t_std,
            100.0 * (t_mean / paper.contact_time_ratio - 1.0),
            f_mean * 1e9,
            f_std * 1e9,
            100.0 * (f_mean / paper.max_force - 1.0),
        );
        results.push((e_mean, e_std));
    }
    let (a, b) = (results[0], results[1]);
    println!(
        "separation |ΔE| / σ_E (one estimate at {rate:.1} Hz): {:.2}; needed > 3",
        (a.0 - b.0).abs() / a.1.max(b.1)
    );
    // The worker's counters: estimates, failures, frames it could not take, rebuilds.
    if let Ok(mut stream) = tokio::net::TcpStream::connect(addr).await {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let request = format!("GET /metrics HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
        let _ = stream.write_all(request.as_bytes()).await;
        let mut body = String::new();
        let _ = stream.read_to_string(&mut body).await;
        for line in body
            .lines()
            .filter(|l| l.starts_with("ftafm_force") || l.starts_with("ftafm_overrun"))
        {
            println!("{line}");
        }
    }
    let _ = stop.send(());
    let _ = server.await;
}
