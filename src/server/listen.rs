//! The accept loop: HTTP/1.1 connections served by hyper with the limits an instrument on a
//! network needs, so no peer can hold the daemon open: a header that is not complete within
//! [`ConnectionLimits::header_timeout`] closes its connection, at most
//! [`ConnectionLimits::max_handshaking`] connections may be open before their upgrade (beyond
//! it a connection gets a 503 at once), and shutdown waits at most
//! [`ConnectionLimits::shutdown_grace`] for the connections still open, then drops them.
//! Upgraded WebSocket sessions are not counted here: they close themselves on shutdown.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Duration;

use axum::Router;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinSet;

/// The limits of [`serve`].
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    /// Longest a client may take to send a request's headers (s).
    pub header_timeout: Duration,
    /// Most HTTP connections open at once that have not upgraded to a WebSocket.
    pub max_handshaking: usize,
    /// Longest shutdown waits for open HTTP connections before dropping them.
    pub shutdown_grace: Duration,
    /// The WebSocket keep-alive: a session that has received nothing for this long is
    /// pinged, and closed (1008 "no pong") if nothing at all comes back within
    /// `/server/stall_timeout`, so a half-open connection cannot hold its slot. Not used by
    /// [`serve`] itself but by the sessions it upgrades; tests make it short.
    pub ping_interval: Duration,
}

/// The keep-alive's default ping interval: well inside the idle timeouts of proxies and NAT
/// tables (often 60 s), and at 20 s a ping costs an idle connection nothing.
pub const PING_INTERVAL: Duration = Duration::from_secs(20);

impl Default for ConnectionLimits {
    fn default() -> Self {
        Self {
            header_timeout: Duration::from_secs(10),
            max_handshaking: 256,
            shutdown_grace: Duration::from_secs(1),
            ping_interval: PING_INTERVAL,
        }
    }
}

/// What the accept loop counts, for `/metrics`.
#[derive(Debug, Default)]
pub struct ConnectionCounters {
    /// HTTP connections open now that have not upgraded.
    pub open: AtomicUsize,
    /// Connections accepted since start.
    pub accepted: AtomicU64,
    /// Connections closed because their headers did not arrive in time.
    pub dropped_header_timeout: AtomicU64,
    /// Connections refused with 503 because too many were open before their upgrade.
    pub dropped_limit: AtomicU64,
    /// Connections still open when the shutdown grace ran out, dropped.
    pub dropped_shutdown: AtomicU64,
}

impl ConnectionCounters {
    /// `(reason, count)` of every kind of dropped connection.
    pub fn dropped(&self) -> [(&'static str, u64); 3] {
        [
            (
                "header_timeout",
                self.dropped_header_timeout.load(Ordering::Relaxed),
            ),
            ("limit", self.dropped_limit.load(Ordering::Relaxed)),
            ("shutdown", self.dropped_shutdown.load(Ordering::Relaxed)),
        ]
    }
}

/// Decrements the open count when a connection's task ends, however it ends.
struct Open(Arc<ConnectionCounters>);

impl Drop for Open {
    fn drop(&mut self) {
        self.0.open.fetch_sub(1, Ordering::Relaxed);
    }
}

/// The 503 a connection over the limit gets, whole.
fn refusal(limit: usize) -> Vec<u8> {
    let body = format!(
        "too many HTTP connections open before their request completed (at most {limit}); \
         retry\n"
    );
    format!(
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n\
         Connection: close\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

/// Serves `app` on `listener` until `shutdown` resolves, then stops accepting, lets open
/// HTTP connections finish for at most `limits.shutdown_grace`, and drops the rest.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    shutdown: impl Future<Output = ()>,
    limits: ConnectionLimits,
    counters: Arc<ConnectionCounters>,
) {
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut connections = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        let (tcp, _peer) = tokio::select! {
            _ = &mut shutdown => break,
            // Reap finished connections so the set does not grow without bound.
            Some(_) = connections.join_next(), if !connections.is_empty() => continue,
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: wait a little rather than spin.
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
        };
        counters.accepted.fetch_add(1, Ordering::Relaxed);
        // Small data frames must not wait for the peer's delayed ACK (Nagle): 12–40 ms of
        // latency otherwise.
        let _ = tcp.set_nodelay(true);
        if counters.open.load(Ordering::Relaxed) >= limits.max_handshaking {
            counters.dropped_limit.fetch_add(1, Ordering::Relaxed);
            // Never wait on the refused peer: what fits in the socket buffer goes, then close.
            let _ = tcp.try_write(&refusal(limits.max_handshaking));
            continue;
        }
        counters.open.fetch_add(1, Ordering::Relaxed);
        let open = Open(counters.clone());
        let service = TowerToHyperService::new(app.clone());
        let mut stop = stop_rx.clone();
        let counters = counters.clone();
        connections.spawn(async move {
            let _open = open;
            let conn = http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(limits.header_timeout)
                .serve_connection(TokioIo::new(tcp), service)
                .with_upgrades();
            tokio::pin!(conn);
            let result = tokio::select! {
                r = conn.as_mut() => r,
                _ = stop.changed() => {
                    conn.as_mut().graceful_shutdown();
                    conn.await
                }
            };
            if let Err(e) = result
                && e.is_timeout()
            {
                counters
                    .dropped_header_timeout
                    .fetch_add(1, Ordering::Relaxed);
            }
        });
    }
    drop(listener);
    let _ = stop_tx.send(true);
    let finished = tokio::time::timeout(limits.shutdown_grace, async {
        while connections.join_next().await.is_some() {}
    })
    .await;
    if finished.is_err() {
        counters
            .dropped_shutdown
            .fetch_add(connections.len() as u64, Ordering::Relaxed);
        connections.abort_all();
        while connections.join_next().await.is_some() {}
    }
}
