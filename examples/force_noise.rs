//! How well the live FT-AFM inversion tells silicon (129 GPa) from the 10 % softer
//! inhomogeneity (116.1 GPa) with the instrument's default noise and 1 kHz output:
//! runs the daemon in-process, collects `force` estimates on each material over the
//! protocol, and prints mean, standard deviation and the separation in σ.
//!
//! `cargo run --release --example force_noise -- [estimates per material] [method] [averaging]`

use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn send(ws: &mut Ws, request: Value) {
    ws.send(Message::Text(request.to_string().into()))
        .await
        .expect("send");
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

fn stats(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(2000);
    let method = args.next().unwrap_or_else(|| "two_harmonic".into());
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
    println!(
        "default noise (T = {} K, detector {} m/√Hz, {}-bit ADC), demodulators order {} τ = {} s at {} Hz, method {method}, averaging {averaging} frames, {n} estimates per material",
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
        tokio::time::sleep(Duration::from_millis(300)).await;
        for _ in 0..(400 / averaging).max(3) {
            next_force(&mut ws).await; // settle: what was queued during the change
        }
        let (mut e, mut tau, mut f, mut sigma_e) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        while e.len() < n {
            let v = next_force(&mut ws).await;
            e.push(v["youngs_modulus"].as_f64().unwrap_or(f64::NAN));
            tau.push(v["contact_time_ratio"].as_f64().unwrap_or(f64::NAN));
            f.push(v["max_force"].as_f64().unwrap_or(f64::NAN));
            sigma_e.push(v["youngs_modulus_sigma"].as_f64().unwrap_or(f64::NAN));
        }
        let (e_mean, e_std) = stats(&e);
        let (t_mean, t_std) = stats(&tau);
        let (f_mean, f_std) = stats(&f);
        let (s_mean, _) = stats(&sigma_e);
        println!(
            "E set {:.1} GPa: E = {:.1} ± {:.1} GPa (reported σ {:.1}), τ = {:.5} ± {:.5}, F = {:.2} ± {:.2} nN",
            modulus / 1e9,
            e_mean / 1e9,
            e_std / 1e9,
            s_mean / 1e9,
            t_mean,
            t_std,
            f_mean * 1e9,
            f_std * 1e9
        );
        results.push((e_mean, e_std));
    }
    let (a, b) = (results[0], results[1]);
    println!(
        "separation |ΔE| / σ_E (one estimate at {:.0} Hz): {:.2}; needed > 3",
        1000.0 / averaging as f64,
        (a.0 - b.0).abs() / a.1.max(b.1)
    );
    let _ = stop.send(());
    let _ = server.await;
}
