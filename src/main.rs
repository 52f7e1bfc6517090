//! The `ftafm` command: parse the command line, load the configuration, call the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use ftafm::cli::analyse::{AnalyseArgs, RecordSignalArgs};
use ftafm::cli::fm_invert::FmInvertArgs;
use ftafm::cli::replay::ReplayArgs;
use ftafm::cli::{self, ConfigArg, serve::ServeArgs};

#[derive(Parser)]
#[command(
    name = "ftafm",
    version,
    about = "Real-time virtual instrument for Fourier-transform AFM",
    after_help = "Without a command, ftafm runs `serve` (and takes its flags: `ftafm --config \
                  FILE --bind ADDR`). --preset and --config go before or after the command \
                  (`ftafm --preset pdms info`); presets apply in the order given."
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// The configuration flags before the command; they come first, then the command's own.
    #[command(flatten)]
    config: ConfigArg,
    /// `serve`'s address, for `ftafm` without a command (default 127.0.0.1:8700).
    #[arg(long, value_name = "ADDR")]
    bind: Option<String>,
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
    /// Analyse a recorded photodiode signal offline: the lock-in bank, spectrum and force
    /// inversion of the configuration, streamed from the file (docs/analyse.md).
    Analyse(AnalyseArgs),
    /// Write the synthesiser's own signal (through the ADC) to a .npy file in metres, with
    /// the drive's phase in a sidecar, for `ftafm analyse`.
    RecordSignal(RecordSignalArgs),
    /// Replay a recorded photodiode signal into a running daemon as its streamed source
    /// (/source/kind = "stream"), in real time or --fast, once or --loop
    /// (docs/protocol.md, "Streaming samples in").
    Replay(ReplayArgs),
    /// Invert an FM-AFM frequency-shift curve Δf(z) (CSV `z,df`) to the force F(z) by the
    /// Sader–Jarvis formula (docs/loops.md).
    FmInvert(FmInvertArgs),
    /// Print the configured instrument: its modes and the 1-DOF tapping solution.
    Info {
        #[command(flatten)]
        config: ConfigArg,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let command = match (cli.command, cli.bind) {
        (None, bind) => Command::Serve(ServeArgs {
            config: ConfigArg::default(),
            bind: bind.unwrap_or_else(|| cli::serve::DEFAULT_BIND.to_owned()),
        }),
        (Some(_), Some(_)) => {
            eprintln!(
                "ftafm: --bind is serve's flag: put it after the command (`ftafm serve --bind ADDR`)"
            );
            return ExitCode::from(cli::EXIT_USAGE);
        }
        (Some(command), None) => command,
    };
    let command = match with_leading_config(command, cli.config) {
        Ok(command) => command,
        Err(e) => {
            eprintln!("ftafm: {e}");
            return ExitCode::from(cli::EXIT_USAGE);
        }
    };
    if let Err(e) = ftafm::cpu::isa_from_env() {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    if matches!(command, Command::Serve(_) | Command::Soak { .. }) {
        // The daemon and the WebSocket client keep Rust's ignored SIGPIPE: a peer that
        // closes its socket is an error to handle, not a reason to die.
    } else {
        // The other commands write reports for pipes (`ftafm info | head -1`): a reader that
        // closes early ends them quietly, as it does any Unix tool.
        cli::restore_sigpipe();
    }
    if matches!(command, Command::Serve(_)) {
        // Before anything slow (the config's orbit, the pipeline's start): a SIGTERM or
        // Ctrl-C during start-up must stop the daemon cleanly, not kill it by signal.
        cli::serve::stop_signal::install();
    }
    let result = match command {
        Command::Serve(ServeArgs { config, bind }) => cli::serve::command(&config, &bind),
        Command::Paper {
            config,
            inhomogeneity_factor,
            engine,
            json,
        } => cli::paper::command(&config, inhomogeneity_factor, engine.as_deref(), json),
        Command::Info { config } => cli::info::command(&config),
        Command::Presets { json } => cli::presets::command(json),
        Command::Scan {
            config,
            frames,
            out,
            realtime,
            json,
        } => cli::scan::command(&config, frames, out, realtime, json),
        Command::Bench {
            config,
            seconds,
            realtime,
            json,
        } => cli::bench::command(&config, seconds, realtime, json),
        Command::Soak {
            url,
            clients,
            seconds,
            streams,
            json,
            fail_on_loss,
            report,
        } => cli::soak::command(url, clients, seconds, &streams, json, fail_on_loss, report),
        Command::Stalls { seconds, json } => cli::stalls::command(seconds, json),
        Command::Analyse(args) => cli::analyse::command(args),
        Command::RecordSignal(args) => cli::analyse::record_signal(args),
        Command::Replay(args) => cli::replay::command(args),
        Command::FmInvert(args) => cli::fm_invert::command(args),
    };
    result.unwrap_or_else(|code| code)
}

/// `command` with the --preset/--config flags given before it put first; refused for the
/// commands that read no configuration.
fn with_leading_config(mut command: Command, leading: ConfigArg) -> Result<Command, String> {
    let own = match &mut command {
        Command::Serve(ServeArgs { config, .. })
        | Command::Paper { config, .. }
        | Command::Scan { config, .. }
        | Command::Bench { config, .. }
        | Command::Info { config }
        | Command::Analyse(AnalyseArgs { config, .. })
        | Command::RecordSignal(RecordSignalArgs { config, .. }) => config,
        Command::Presets { .. }
        | Command::Soak { .. }
        | Command::Stalls { .. }
        | Command::Replay(_)
        | Command::FmInvert(_) => {
            return if leading.is_empty() {
                Ok(command)
            } else {
                Err(
                    "--preset and --config do not apply to this command: it reads no \
                     configuration"
                        .to_owned(),
                )
            };
        }
    };
    *own = leading.then(std::mem::take(own))?;
    Ok(command)
}
