//! The HTTP side: routes, the WebSocket handshake (origin and capacity checks), and
//! [`run`], which serves until a shutdown future resolves.

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{OriginalUri, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use tokio::net::TcpListener;
use tokio::sync::watch;

use super::listen::{ConnectionCounters, ConnectionLimits};
use super::protocol::MAX_SAMPLE_FRAME_BYTES;
use super::state::AppState;
use super::{assets, hub, metrics, session};
use crate::config::Settings;
use crate::instrument::Control;
use crate::instrument::sweeper::SweeperLinks;
use crate::pipeline::{Pipeline, PipelineError};

/// Why the daemon stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// The pipeline could not start.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// Serving failed.
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
}

/// Runs the daemon on `listener` with `settings` until `shutdown` resolves; then closes
/// every WebSocket (1001), stops the pipeline's threads and returns. Bind the listener to
/// `127.0.0.1:0` in tests.
pub async fn run(
    listener: TcpListener,
    settings: Settings,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    run_with(listener, settings, shutdown, ConnectionLimits::default()).await
}

/// [`run`] with the connection limits given (header timeout, connections before their
/// upgrade, shutdown grace, WebSocket keep-alive): tests make them small.
pub async fn run_with(
    listener: TcpListener,
    settings: Settings,
    shutdown: impl Future<Output = ()> + Send + 'static,
    limits: ConnectionLimits,
) -> Result<(), ServerError> {
    let (shutdown_tx, shutdown_rx) = watch::channel(false);
    let (force, estimates) = crate::instrument::force::ForceLink::start();
    force.follow(0, None, Some(settings.clone()));
    let (image, image_lines) = crate::instrument::image::ImageLink::start(&settings);
    let stall = crate::pipeline::StallMeter::start("ftafm-stall")
        .inspect_err(|e| tracing::warn!(error = %e, "no stall meter: its thread would not start"))
        .ok();
    // Last, so that no frame waits for the rest of the start-up before the hub takes it.
    let (pipeline, output) = Pipeline::start(&settings)?;
    let inlet = output.inlet.clone();
    let queue_bytes = settings.server.client_queue_bytes as usize;
    let sample_rate = settings.synth.sample_rate;
    let control = Arc::new(Control::new(settings, Some(pipeline)));
    let state = Arc::new(AppState {
        sample_rate,
        control,
        clients: Mutex::new(Vec::new()),
        connections: std::sync::atomic::AtomicUsize::new(0),
        next_client: AtomicU64::new(1),
        streams: Default::default(),
        shutdown: shutdown_rx,
        started: Instant::now(),
        refused_origin: AtomicU64::new(0),
        refused_capacity: AtomicU64::new(0),
        refused_host: AtomicU64::new(0),
        queue_bytes: std::sync::atomic::AtomicUsize::new(queue_bytes),
        closed_stalled: AtomicU64::new(0),
        closed_unresponsive: AtomicU64::new(0),
        ping_interval: limits.ping_interval,
        http: Arc::new(ConnectionCounters::default()),
        latency_totals: Mutex::new(Default::default()),
        force: Arc::new(force),
        image,
        stall,
        latest_demods: Mutex::new(None),
        sweep_frames: Arc::new(crate::instrument::tap::FrameTap::new()),
        sweep_force: Arc::new(crate::instrument::tap::Tap::new()),
        inlet,
    });
    state
        .control
        .set_followers(super::follow::followers(Arc::downgrade(&state)));
    let hub = tokio::spawn(hub::run(state.clone(), output, estimates, image_lines));
    let publisher = state.clone();
    let sweeper = tokio::spawn(crate::instrument::sweeper::run(SweeperLinks {
        control: state.control.clone(),
        frames: state.sweep_frames.clone(),
        forces: state.sweep_force.clone(),
        force: state.force.clone(),
        shutdown: state.shutdown.clone(),
        publish: Box::new(move |t, t_synth_ns, fields| {
            hub::publish_sweep(&publisher, t, t_synth_ns, fields)
        }),
    }));
    // Every route but /healthz checks that the request names this server (DNS rebinding);
    // every response carries the security headers.
    let app = Router::new()
        .route("/ws", get(websocket))
        .route("/metrics", get(metrics_text))
        .route("/image/{file}", get(image_file))
        .fallback(get(asset))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            super::host::guard,
        ))
        .route("/healthz", get(healthz))
        .layer(axum::middleware::from_fn(super::host::security_headers))
        .with_state(state.clone());
    let signal = async move {
        shutdown.await;
        tracing::info!("shutting down");
        let _ = shutdown_tx.send(true);
    };
    super::listen::serve(listener, app, signal, limits, state.http.clone()).await;
    // Sessions close themselves on the signal; give them a moment to say goodbye.
    let deadline = Instant::now() + Duration::from_millis(1500);
    while state.client_count() > 0 && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let _ = hub.await;
    // The sweeper ends on the shutdown signal; a change it awaits takes milliseconds.
    let _ = tokio::time::timeout(Duration::from_secs(2), sweeper).await;
    if let Some(counters) = state.control.stop().await {
        tracing::info!(
            samples = counters.samples_processed,
            overruns = counters.overrun_samples,
            "pipeline stopped"
        );
    }
    Ok(())
}

/// The dashboard's files (`web/`, embedded); 404 for anything else.
async fn asset(OriginalUri(uri): OriginalUri) -> Response {
    match assets::find(uri.path()) {
        // no-cache: a page left open across a daemon upgrade revalidates its scripts.
        Some(a) => (
            [
                (header::CONTENT_TYPE, a.content_type),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            a.body,
        )
            .into_response(),
        None => (
            StatusCode::NOT_FOUND,
            format!("no such page: {}\n", uri.path()),
        )
            .into_response(),
    }
}

/// `GET /image/<channel>.gsf` or `.npy`: a channel of the last finished scan frame, as a
/// Gwyddion Simple Field or a NumPy array (docs/protocol.md, "Image export").
async fn image_file(
    State(state): State<Arc<AppState>>,
    axum::extract::Path(file): axum::extract::Path<String>,
) -> Response {
    let not_found = |msg: String| (StatusCode::NOT_FOUND, msg + "\n").into_response();
    let Some((name, ext)) = file.rsplit_once('.') else {
        return not_found(format!("{file}: ask for <channel>.gsf or <channel>.npy"));
    };
    if ext != "gsf" && ext != "npy" && ext != "json" {
        return not_found(format!(
            "{file}: the formats are .gsf (Gwyddion), .npy (NumPy) and .json (the .npy's \
             unit, geometry and settings)"
        ));
    }
    let frame = state.image.last_frame.lock().ok().and_then(|f| f.clone());
    let Some(frame) = frame else {
        return not_found(
            "no scan frame has finished yet: set /scan/enable true and wait for its last line"
                .into(),
        );
    };
    let Some(channel) = frame.channels.iter().find(|c| c.name == name) else {
        let names: Vec<&str> = frame.channels.iter().map(|c| c.name.as_str()).collect();
        return not_found(format!(
            "no channel {name:?}; the last frame has {}",
            names.join(", ")
        ));
    };
    use crate::imaging::export;
    let meta = export::Metadata::of(&frame, std::time::SystemTime::now());
    let body = match ext {
        "gsf" => export::gsf(channel, frame.pixels, frame.size, frame.origin, &meta),
        "npy" => export::npy(channel, frame.pixels),
        _ => export::npy_companion(channel, frame.pixels, frame.size, frame.origin, &meta)
            .into_bytes(),
    };
    let content_type = if ext == "json" {
        "application/json"
    } else {
        "application/octet-stream"
    };
    let disposition = format!(
        "attachment; filename=\"ftafm-g{}-f{}-{name}.{ext}\"",
        frame.generation, frame.frame
    );
    (
        [
            (header::CONTENT_TYPE, content_type.to_owned()),
            (header::CONTENT_DISPOSITION, disposition),
            (header::CACHE_CONTROL, "no-store".to_owned()),
        ],
        body,
    )
        .into_response()
}

/// Longest the pipeline may go without finishing a block before `/healthz` reports it
/// stalled: far beyond any scheduling hiccup (the sample ring itself holds 0.5 s), far
/// below what an operator would call running.
const STALL_LIMIT_NS: u64 = 2_000_000_000;

/// `GET /healthz`: 200 `ok` while the pipeline runs; 503 with the reason while it starts
/// (nothing processed yet) or when a real-time thread has finished no block for
/// [`STALL_LIMIT_NS`] (wedged, or starved of samples by a wedged synthesiser).
async fn healthz(State(state): State<Arc<AppState>>) -> Response {
    let streaming = state.inlet.accepting();
    match health(state.control.counters().as_ref(), streaming) {
        Ok(()) if streaming => (StatusCode::OK, "ok (source: stream)\n").into_response(),
        Ok(()) => (StatusCode::OK, "ok\n").into_response(),
        Err(reason) => (StatusCode::SERVICE_UNAVAILABLE, reason + "\n").into_response(),
    }
}

/// The pipeline's health from its counters (`None`: no pipeline): why it is not healthy.
/// With a streamed source (`streaming`) a DSP thread with nothing to do while the
/// synthesiser thread waits on the feed is waiting for the writer, not stalled.
fn health(
    counters: Option<&crate::pipeline::CountersSnapshot>,
    streaming: bool,
) -> Result<(), String> {
    let Some(c) = counters else {
        return Err("unhealthy: no pipeline is running".into());
    };
    let waiting = streaming
        && c.synth_idle_ns <= STALL_LIMIT_NS
        && c.samples_processed + c.overrun_samples >= c.samples_synthesized;
    if waiting {
        return Ok(());
    }
    if c.samples_processed == 0 {
        return Err("starting".into());
    }
    let seconds = |ns: u64| ns as f64 * 1e-9;
    if c.dsp_idle_ns > STALL_LIMIT_NS {
        return Err(format!(
            "unhealthy: the pipeline has stalled: the DSP thread has processed no samples for \
             {:.1} s (samples_processed = {}; the synthesiser's last block was {:.1} s ago)",
            seconds(c.dsp_idle_ns),
            c.samples_processed,
            seconds(c.synth_idle_ns)
        ));
    }
    if c.synth_idle_ns > STALL_LIMIT_NS {
        return Err(format!(
            "unhealthy: the pipeline has stalled: the synthesiser has produced no samples for \
             {:.1} s (samples_synthesized = {})",
            seconds(c.synth_idle_ns),
            c.samples_synthesized
        ));
    }
    Ok(())
}

async fn metrics_text(State(state): State<Arc<AppState>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        metrics::render(&state),
    )
        .into_response()
}

/// Whether a browser page from `origin` may open the WebSocket: the server's own origin
/// (same host as the request) or one listed in `/server/allowed_origins`.
fn origin_allowed(origin: &str, host: Option<&str>, allowed: &[String]) -> bool {
    let own =
        host.is_some_and(|h| origin == format!("http://{h}") || origin == format!("https://{h}"));
    own || allowed.iter().any(|a| a == origin)
}

async fn websocket(
    State(state): State<Arc<AppState>>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    let settings = state.control.settings();
    let (allowed, max_clients, queue) = (
        settings.server.allowed_origins.clone(),
        settings.server.max_clients as usize,
        settings.server.client_queue as usize,
    );
    if headers.get_all(header::ORIGIN).iter().count() > 1 {
        state.refused_origin.fetch_add(1, Ordering::Relaxed);
        return (
            StatusCode::FORBIDDEN,
            "two Origin headers: a browser sends one; refused\n",
        )
            .into_response();
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let origin = origin.to_str().unwrap_or("");
        let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
        if !origin_allowed(origin, host, &allowed) {
            state.refused_origin.fetch_add(1, Ordering::Relaxed);
            tracing::warn!(origin, "WebSocket refused: origin not allowed");
            return (
                StatusCode::FORBIDDEN,
                format!("origin {origin} may not open the WebSocket; add it to /server/allowed_origins\n"),
            )
                .into_response();
        }
    }
    let reserved = state
        .connections
        .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| {
            (n < max_clients).then_some(n + 1)
        })
        .is_ok();
    if !reserved {
        state.refused_capacity.fetch_add(1, Ordering::Relaxed);
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("too many clients: at most {max_clients} (/server/max_clients)\n"),
        )
            .into_response();
    }
    let failed = state.clone();
    upgrade
        // Text frames are held to MAX_MESSAGE_BYTES by the session; binary ones carry
        // streamed samples.
        .max_message_size(MAX_SAMPLE_FRAME_BYTES)
        .max_frame_size(MAX_SAMPLE_FRAME_BYTES)
        .on_failed_upgrade(move |_| {
            failed.connections.fetch_sub(1, Ordering::SeqCst);
        })
        .on_upgrade(move |socket| async move {
            session::run(socket, state.clone(), queue).await;
            state.connections.fetch_sub(1, Ordering::SeqCst);
        })
}

#[cfg(test)]
mod tests {
    use super::{STALL_LIMIT_NS, health, origin_allowed};
    use crate::pipeline::CountersSnapshot;

    #[test]
    fn health_follows_the_heartbeats() {
        assert!(health(None, false).unwrap_err().contains("no pipeline"));
        let mut c = CountersSnapshot::default();
        assert_eq!(health(Some(&c), false).unwrap_err(), "starting");
        c.samples_processed = 4096;
        c.samples_synthesized = 4096;
        assert_eq!(health(Some(&c), false), Ok(()));
        c.dsp_idle_ns = STALL_LIMIT_NS + 1;
        let reason = health(Some(&c), false).unwrap_err();
        assert!(reason.contains("DSP thread"), "{reason}");
        // A streamed source with nothing streamed in: waiting, not stalled; with samples
        // waiting in the ring that the DSP does not take, stalled.
        assert_eq!(health(Some(&c), true), Ok(()));
        c.samples_synthesized += 4096;
        let reason = health(Some(&c), true).unwrap_err();
        assert!(reason.contains("DSP thread"), "{reason}");
        c.dsp_idle_ns = 0;
        c.synth_idle_ns = STALL_LIMIT_NS + 1;
        let reason = health(Some(&c), false).unwrap_err();
        assert!(reason.contains("synthesiser"), "{reason}");
        let reason = health(Some(&c), true).unwrap_err();
        assert!(reason.contains("synthesiser"), "{reason}");
    }

    #[test]
    fn origins() {
        let allowed = vec!["http://lab.example:3000".to_string()];
        assert!(origin_allowed(
            "http://127.0.0.1:8700",
            Some("127.0.0.1:8700"),
            &[]
        ));
        assert!(origin_allowed(
            "http://lab.example:3000",
            Some("127.0.0.1:8700"),
            &allowed
        ));
        assert!(!origin_allowed(
            "http://evil.example",
            Some("127.0.0.1:8700"),
            &allowed
        ));
        assert!(!origin_allowed(
            "http://127.0.0.1:8701",
            Some("127.0.0.1:8700"),
            &[]
        ));
        assert!(!origin_allowed("null", None, &[]));
    }
}
