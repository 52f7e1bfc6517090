//! The `ftafm` command: parse the command line, load the configuration, call the library.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};

use ftafm::config::{self, Settings};
use ftafm::paper;

#[derive(Parser)]
#[command(
    name = "ftafm",
    version,
    about = "Real-time virtual instrument for Fourier-transform AFM",
    after_help = "Without a command, ftafm runs `serve` (and takes its flags: `ftafm --config \
                  FILE --bind ADDR`).",
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// `serve`'s flags, for `ftafm` without a command.
    #[command(flatten)]
    serve: ServeArgs,
}

/// The daemon's flags: `ftafm serve …` and bare `ftafm …`.
#[derive(clap::Args)]
struct ServeArgs {
    #[command(flatten)]
    config: ConfigArg,
    /// Address to listen on, IP:PORT or HOST:PORT (e.g. localhost:8799); loopback by
    /// default (other hosts only if you mean it: the instrument has no authentication).
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:8700")]
    bind: String,
}

/// The configuration flags every command shares.
#[derive(clap::Args)]
struct ConfigArg {
    /// A real cantilever or sample (`ftafm presets` lists them) overlaid on the embedded
    /// default, in the order given, before --config; e.g. --preset tap300 --preset mica.
    #[arg(long, value_name = "NAME")]
    preset: Vec<String>,
    /// TOML file overlaid on the embedded default configuration (after the presets).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the instrument daemon: dashboard at /, WebSocket at /ws, /metrics, /healthz.
    Serve(ServeArgs),
    /// Compute the paper's Table 1 and Fig. 3 offline for the configured instrument.
    Paper {
        #[command(flatten)]
        config: ConfigArg,
        /// Young's modulus of the inhomogeneity relative to the sample's (0 < F, F·E ≤ 10 TPa).
        #[arg(
            long,
            value_name = "F",
            default_value_t = 0.9,
            allow_negative_numbers = true
        )]
        inhomogeneity_factor: f64,
        /// The engine: "paper" (the 1-DOF method) or "coupled" (all modes, contact from the
        /// tip position, physics.md §6); default: the configured /synth/engine. Without
        /// --json both are shown side by side.
        #[arg(long, value_name = "ENGINE")]
        engine: Option<String>,
        /// Print exactly one JSON object on stdout instead of tables.
        #[arg(long)]
        json: bool,
    },
    /// Record scan frames without the daemon (free-running unless --realtime), write each
    /// channel as .gsf (Gwyddion) and .npy (NumPy), and report contrast and CNR per region.
    Scan {
        #[command(flatten)]
        config: ConfigArg,
        /// Frames to record (1 ≤ N ≤ 1000).
        #[arg(
            long,
            value_name = "N",
            default_value_t = 1,
            allow_negative_numbers = true
        )]
        frames: i64,
        /// Directory for the image files (created if missing); without it nothing is written.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Pace the chain by the wall clock, as the daemon does, instead of free-running.
        #[arg(long)]
        realtime: bool,
        /// Print exactly one JSON object on stdout (progress still goes to stderr).
        #[arg(long)]
        json: bool,
    },
    /// Run the whole signal chain on its threads and measure throughput (or, with
    /// --realtime, soak it at the wall-clock rate and count overruns).
    Bench {
        #[command(flatten)]
        config: ConfigArg,
        /// Duration of the run in seconds (0 < S ≤ 86400).
        #[arg(
            long,
            value_name = "S",
            default_value_t = 10.0,
            allow_negative_numbers = true
        )]
        seconds: f64,
        /// Pace the chain by the wall clock, as the daemon does, instead of free-running.
        #[arg(long)]
        realtime: bool,
        /// Print exactly one JSON object on stdout (progress still goes to stderr).
        #[arg(long)]
        json: bool,
    },
    /// Measure this machine's own stalls, with nothing of ftafm running: a thread naps 1 ms
    /// at a time and reports how much later than asked it woke up.
    Stalls {
        /// Duration of the measurement in seconds (0 < S ≤ 86400).
        #[arg(
            long,
            value_name = "S",
            default_value_t = 60.0,
            allow_negative_numbers = true
        )]
        seconds: f64,
        /// Print exactly one JSON object on stdout (progress still goes to stderr).
        #[arg(long)]
        json: bool,
    },
    /// Soak a running daemon with N WebSocket clients: receive latency, seq gaps,
    /// disconnects, and the server's overruns and drops from /metrics.
    Soak {
        /// WebSocket URL of the daemon.
        #[arg(long, value_name = "URL", default_value = "ws://127.0.0.1:8700/ws")]
        url: String,
        /// Number of concurrent clients (1 ≤ N ≤ 1024).
        #[arg(
            long,
            value_name = "N",
            default_value_t = 16,
            allow_negative_numbers = true
        )]
        clients: i64,
        /// Duration of the measurement in seconds (0 < S ≤ 86400).
        #[arg(
            long,
            value_name = "S",
            default_value_t = 10.0,
            allow_negative_numbers = true
        )]
        seconds: f64,
        /// Comma-separated streams each client subscribes to (demods, spectrum, scope,
        /// status, force).
        #[arg(long, value_name = "LIST", default_value = "demods")]
        streams: String,
        /// Print exactly one JSON object as the last line of stdout (progress on stderr).
        #[arg(long)]
        json: bool,
        /// Exit with status 1 if any overrun, late block (the synthesiser fell more than
        /// 0.1 s behind the clock and skipped that signal time) or seq gap occurred (for CI).
        #[arg(long)]
        fail_on_loss: bool,
        /// Write the HTML report (summary, latency histogram, latency over time) here;
        /// default: ftafm-soak-<unix time>.html in the temporary directory. Its path is
        /// printed on stderr at the end.
        #[arg(long, value_name = "FILE")]
        report: Option<PathBuf>,
    },
    /// List the presets: real cantilevers and samples, with their sources.
    Presets {
        /// Print exactly one JSON array on stdout (name, kind, summary, toml).
        #[arg(long)]
        json: bool,
    },
    /// Print the configured instrument: its modes and the 1-DOF tapping solution.
    Info {
        #[command(flatten)]
        config: ConfigArg,
    },
}

/// Exit status for bad arguments or an invalid configuration (contract.md).
const EXIT_USAGE: u8 = 2;

fn load(args: &ConfigArg) -> Result<Settings, ExitCode> {
    config::load_with_presets(&args.preset, args.config.as_deref()).map_err(|e| {
        eprintln!("ftafm: invalid configuration: {e}");
        ExitCode::from(EXIT_USAGE)
    })
}

fn run_presets(json: bool) -> Result<ExitCode, ExitCode> {
    if json {
        println!(
            "{}",
            serde_json::to_string(&config::PRESETS).expect("plain strings")
        );
        return Ok(ExitCode::SUCCESS);
    }
    for kind in [config::PresetKind::Cantilever, config::PresetKind::Sample] {
        println!(
            "{}:",
            match kind {
                config::PresetKind::Cantilever => "cantilevers ([cantilever])",
                config::PresetKind::Sample => "samples ([sample]; inclusions follow)",
            }
        );
        for p in config::PRESETS.iter().filter(|p| p.kind == kind) {
            println!("  {:<14} {}", p.name, p.summary());
        }
    }
    println!("use: ftafm --preset tap300 --preset polystyrene; sources: config/presets/NAME.toml");
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let command = cli.command.unwrap_or(Command::Serve(cli.serve));
    if matches!(command, Command::Serve(_)) {
        // Before anything slow (the config's orbit, the pipeline's start): a SIGTERM or
        // Ctrl-C during start-up must stop the daemon cleanly, not kill it by signal.
        stop_signal::install();
    }
    let result = match command {
        Command::Serve(ServeArgs { config, bind }) => run_serve(&config, &bind),
        Command::Paper {
            config,
            inhomogeneity_factor,
            engine,
            json,
        } => run_paper(&config, inhomogeneity_factor, engine.as_deref(), json),
        Command::Info { config } => run_info(&config),
        Command::Presets { json } => run_presets(json),
        Command::Scan {
            config,
            frames,
            out,
            realtime,
            json,
        } => run_scan(&config, frames, out, realtime, json),
        Command::Bench {
            config,
            seconds,
            realtime,
            json,
        } => run_bench(&config, seconds, realtime, json),
        Command::Soak {
            url,
            clients,
            seconds,
            streams,
            json,
            fail_on_loss,
            report,
        } => run_soak(url, clients, seconds, &streams, json, fail_on_loss, report),
        Command::Stalls { seconds, json } => run_stalls(seconds, json),
    };
    result.unwrap_or_else(|code| code)
}

fn run_paper(
    config: &ConfigArg,
    factor: f64,
    engine: Option<&str>,
    json: bool,
) -> Result<ExitCode, ExitCode> {
    let settings = load(config)?;
    let engine = match engine {
        None => settings.synth.engine,
        Some(name) => config::Engine::from_name(name).ok_or_else(|| {
            eprintln!(
                "ftafm: --engine = {name:?} is not an engine: allowed \"paper\", \"coupled\""
            );
            ExitCode::from(EXIT_USAGE)
        })?,
    };
    let modulus = settings.sample.youngs_modulus * factor;
    if !(factor.is_finite() && factor > 0.0 && modulus <= config::MAX_YOUNGS_MODULUS) {
        eprintln!(
            "ftafm: --inhomogeneity-factor = {factor} is out of range: allowed 0 < F and \
             F × /sample/youngs_modulus ({:e} Pa) ≤ {:e} Pa",
            settings.sample.youngs_modulus,
            config::MAX_YOUNGS_MODULUS
        );
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let computed = |engine| {
        paper::compute_with(&settings, factor, engine).map_err(|e| {
            eprintln!("ftafm: {e}");
            ExitCode::FAILURE
        })
    };
    let report = computed(engine)?;
    if json {
        let text =
            serde_json::to_string(&report).expect("the report has no maps with non-string keys");
        println!("{text}");
    } else {
        let paper_case = paper::is_paper_case(&settings) && factor == 0.9;
        println!("Engine: {}", report.engine);
        print!("{}", paper::render_text(&report, paper_case));
        let other = computed(match engine {
            config::Engine::Paper => config::Engine::Coupled,
            config::Engine::Coupled => config::Engine::Paper,
        })?;
        let (p, c) = match engine {
            config::Engine::Paper => (&report, &other),
            config::Engine::Coupled => (&other, &report),
        };
        println!();
        print!("{}", paper::render_engines(p, c));
    }
    Ok(ExitCode::SUCCESS)
}

fn run_serve(config: &ConfigArg, bind: &str) -> Result<ExitCode, ExitCode> {
    let addrs = bind_addresses(bind)?;
    let settings = load(config)?;
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
        ftafm::server::run(listener, settings, shutdown_signal()).await.map_err(|e| {
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
mod stop_signal {
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

fn run_bench(
    config: &ConfigArg,
    seconds: f64,
    realtime: bool,
    json: bool,
) -> Result<ExitCode, ExitCode> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 86_400.0) {
        eprintln!("ftafm: --seconds = {seconds} is out of range: allowed 0 < S ≤ 86400");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let settings = load(config)?;
    let report = ftafm::bench::run(&settings, seconds, realtime, |t, c| {
        eprintln!(
            "[{t:>5.0} s] {:.1} M samples processed, overruns {}, ring {} samples",
            c.samples_processed as f64 / 1e6,
            c.overrun_samples,
            c.ring_fill
        );
    })
    .map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, ftafm::bench::render_text);
    Ok(ExitCode::SUCCESS)
}

fn run_stalls(seconds: f64, json: bool) -> Result<ExitCode, ExitCode> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 86_400.0) {
        eprintln!("ftafm: --seconds = {seconds} is out of range: allowed 0 < S ≤ 86400");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let report = ftafm::soak::measure_stalls(seconds, |t, max_ns, over| {
        eprintln!(
            "[{t:>5.0} s] longest stall so far {:.3} ms, {over} of at least 5 ms",
            max_ns as f64 / 1e6
        );
    })
    .map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, ftafm::soak::render_stalls);
    Ok(ExitCode::SUCCESS)
}

/// A command's report: one JSON object with `--json`, else its text form.
fn print_report<R: serde::Serialize>(json: bool, report: &R, text: impl FnOnce(&R) -> String) {
    if json {
        println!("{}", serde_json::to_string(report).expect("plain numbers"));
    } else {
        print!("{}", text(report));
    }
}

fn run_scan(
    config: &ConfigArg,
    frames: i64,
    out: Option<PathBuf>,
    realtime: bool,
    json: bool,
) -> Result<ExitCode, ExitCode> {
    if !(1..=1000).contains(&frames) {
        eprintln!("ftafm: --frames = {frames} is out of range: allowed 1 ≤ N ≤ 1000");
        return Err(ExitCode::from(EXIT_USAGE));
    }
    let mut settings = load(config)?;
    settings.synth.realtime = realtime;
    let report = ftafm::scan::run(
        &settings,
        frames as usize,
        out.as_deref(),
        |line, lines, frame, wall| {
            eprintln!("[{wall:>5.0} s] frame {frame}, line {line}/{lines}");
        },
    )
    .map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    print_report(json, &report, ftafm::scan::render_text);
    Ok(ExitCode::SUCCESS)
}

fn run_soak(
    url: String,
    clients: i64,
    seconds: f64,
    streams: &str,
    json: bool,
    fail_on_loss: bool,
    html: Option<PathBuf>,
) -> Result<ExitCode, ExitCode> {
    let usage = |message: String| {
        eprintln!("ftafm: {message}");
        ExitCode::from(EXIT_USAGE)
    };
    let clients = usize::try_from(clients)
        .ok()
        .filter(|&n| n <= ftafm::soak::MAX_CLIENTS)
        .ok_or_else(|| {
            usage(format!(
                "--clients = {clients} is out of range: allowed 1 ≤ N ≤ {}",
                ftafm::soak::MAX_CLIENTS
            ))
        })?;
    let options = ftafm::soak::SoakOptions {
        url,
        clients,
        seconds,
        streams: streams
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(String::from)
            .collect(),
    };
    options.validate().map_err(|e| usage(e.to_string()))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .thread_name("ftafm-soak")
        .build()
        .map_err(|e| {
            eprintln!("ftafm: cannot start the async runtime: {e}");
            ExitCode::FAILURE
        })?;
    let report = runtime
        .block_on(ftafm::soak::run(&options, |p| {
            eprintln!(
                "[{:>5.0} s] {} messages, gaps {}, disconnects {}, p99 {:.3} ms",
                p.elapsed,
                p.messages,
                p.gaps,
                p.disconnects,
                p.p99_ns as f64 / 1e6
            );
        }))
        .map_err(|e| match e {
            ftafm::soak::SoakError::InvalidOption { .. } => usage(e.to_string()),
            _ => {
                eprintln!("ftafm: {e}");
                ExitCode::FAILURE
            }
        })?;
    let html = html.unwrap_or_else(|| {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        std::env::temp_dir().join(format!("ftafm-soak-{now}.html"))
    });
    match ftafm::soak::html::write(&report, &html) {
        Ok(()) => eprintln!("ftafm: report written to {}", html.display()),
        Err(e) => eprintln!("ftafm: cannot write the report {}: {e}", html.display()),
    }
    if json {
        println!("{}", serde_json::to_string(&report).expect("plain numbers"));
    } else {
        print!("{}", ftafm::soak::render_text(&report));
    }
    if fail_on_loss && report.lost_anything() {
        eprintln!(
            "ftafm: loss: {} seq gaps, {} overrun samples in {} blocks, {} late blocks",
            report.gaps,
            report.server.overruns,
            report.server.overrun_blocks,
            report.server.late_blocks
        );
        return Err(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

fn run_info(config: &ConfigArg) -> Result<ExitCode, ExitCode> {
    let settings = load(config)?;
    let report = paper::compute(&settings, 1.0).map_err(|e| {
        eprintln!("ftafm: {e}");
        ExitCode::FAILURE
    })?;
    let m = &report.materials[0];
    println!(
        "ftafm {}: {} modes, f1 = {} kHz, k = {} N/m, sample E = {} GPa",
        env!("CARGO_PKG_VERSION"),
        report.modes.len(),
        settings.cantilever.f1 / 1e3,
        settings.cantilever.k,
        settings.sample.youngs_modulus / 1e9
    );
    println!(
        "{:>4}  {:>12}  {:>8}  {:>12}  {:>9}",
        "mode", "f (kHz)", "Q", "K_n (N/m)", "L·φ'(L)"
    );
    for mode in &report.modes {
        println!(
            "{:>4}  {:>12.3}  {:>8.1}  {:>12.4e}  {:>9.4}",
            mode.n,
            mode.frequency / 1e3,
            mode.q,
            mode.stiffness,
            mode.tip_slope
        );
    }
    println!(
        "drive {} kHz{}, sample rate {} MS/s",
        settings.drive.frequency / 1e3,
        if settings.drive.follow_f1 {
            " (follows f1)"
        } else {
            ""
        },
        settings.synth.sample_rate / 1e6
    );
    for warning in settings.warnings() {
        println!("warning: {warning}");
    }
    println!(
        "tapping at A_free = {:.1} nm, A_set = {:.1} nm: F = {:.2} nN, tau = {:.4}, theta = {:.2} deg",
        settings.drive.free_amplitude * 1e9,
        settings.surface.distance * 1e9,
        m.max_force * 1e9,
        m.contact_time_ratio,
        m.phase_shift_deg
    );
    println!("`ftafm serve` runs this instrument live; `ftafm paper` prints the full report");
    Ok(ExitCode::SUCCESS)
}
