//! `ftafm serve` (and bare `ftafm`): the daemon.

use std::process::ExitCode;
use std::time::Duration;

use super::{ConfigArg, EXIT_USAGE, load};

/// The daemon's flags: `ftafm serve …` and bare `ftafm …`.
#[derive(clap::Args)]
pub struct ServeArgs {
    #[command(flatten)]
    pub config: ConfigArg,
    /// Address to listen on, IP:PORT or HOST:PORT (e.g. localhost:8799); loopback by
    /// default (other hosts only if you mean it: the instrument has no authentication).
    #[arg(long, value_name = "ADDR", default_value = DEFAULT_BIND)]
    pub bind: String,
}

/// The daemon's address when --bind is not given.
pub const DEFAULT_BIND: &str = "127.0.0.1:8700";

/// Runs the daemon until SIGTERM or Ctrl-C.
pub fn command(config: &ConfigArg, bind: &str) -> Result<ExitCode, ExitCode> {
    let addrs = bind_addresses(bind)?;
    let settings = load(config)?;
    crate::server::memory::map_large_blocks();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("ftafm-server")
        .build()
        .map_err(|e| {
            eprintln!("ftafm: cannot start the async runtime: {e}");
            ExitCode::FAILURE
        })?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&addrs[..]).await.map_err(|e| {
            eprintln!("ftafm: cannot listen on --bind = {bind:?} ({addrs:?}): {e}");
            ExitCode::FAILURE
        })?;
        let local = listener.local_addr().map_err(|e| {
            eprintln!("ftafm: {e}");
            ExitCode::FAILURE
        })?;
        if !local.ip().is_loopback() {
            tracing::warn!(
                address = %local,
                "listening beyond this machine: the instrument has no authentication, so \
                 anyone who can reach this address can drive it (bind 127.0.0.1 unless you \
                 mean it)"
            );
        }
        println!("ftafm {} — dashboard http://{local}/  WebSocket ws://{local}/ws  metrics http://{local}/metrics", env!("CARGO_PKG_VERSION"));
        crate::server::run(listener, settings, shutdown_signal()).await.map_err(|e| {
            eprintln!("ftafm: {e}");
            ExitCode::FAILURE
        })
    })?;
    Ok(ExitCode::SUCCESS)
}

/// The addresses `--bind` names: an IP:PORT as it is, a HOST:PORT (`localhost:8799`)
/// resolved, IPv4 first (the dashboard's usual `127.0.0.1`); the listener takes the first
/// that binds.
fn bind_addresses(bind: &str) -> Result<Vec<std::net::SocketAddr>, ExitCode> {
    use std::net::ToSocketAddrs;
    let usage = |why: String| {
        eprintln!(
            "ftafm: --bind = {bind:?} {why}: expected IP:PORT or HOST:PORT, e.g. 127.0.0.1:8700 \
             or localhost:8799"
        );
        ExitCode::from(EXIT_USAGE)
    };
    if let Ok(addr) = bind.parse::<std::net::SocketAddr>() {
        return Ok(vec![addr]);
    }
    let Some((_, port)) = bind.rsplit_once(':') else {
        return Err(usage("has no port".into()));
    };
    if port.parse::<u16>().is_err() {
        return Err(usage(format!("has no valid port ({port:?}: 0 to 65535)")));
    }
    let mut addrs: Vec<_> = bind
        .to_socket_addrs()
        .map_err(|e| usage(format!("does not resolve ({e})")))?
        .collect();
    addrs.sort_by_key(|a| !a.is_ipv4());
    if addrs.is_empty() {
        return Err(usage("resolves to no address".into()));
    }
    Ok(addrs)
}

/// SIGTERM and SIGINT as a flag, from the first moment of `serve`.
pub mod stop_signal {
    use std::sync::atomic::{AtomicBool, Ordering};

    static STOP: AtomicBool = AtomicBool::new(false);

    #[cfg(unix)]
    extern "C" fn on_signal(_: libc::c_int) {
        // Async-signal-safe: one atomic store.
        STOP.store(true, Ordering::SeqCst);
    }

    /// Turns SIGTERM and SIGINT into the flag [`requested`] reads.
    pub fn install() {
        #[cfg(unix)]
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe; the
        // function pointer has the signature `signal` expects.
        unsafe {
            let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            libc::signal(libc::SIGTERM, handler);
            libc::signal(libc::SIGINT, handler);
        }
    }

    /// Whether a stop was asked for.
    pub fn requested() -> bool {
        STOP.load(Ordering::SeqCst)
    }
}

/// Resolves once SIGINT (Ctrl-C) or SIGTERM has arrived, also one that arrived during
/// start-up.
async fn shutdown_signal() {
    while !stop_signal::requested() {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}
