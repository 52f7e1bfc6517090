//! The instrument's health as clients see it (`status` stream, `/metrics`).

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

use crate::pipeline::CountersSnapshot;
use crate::pipeline::realtime::Promotion;

/// Latency percentiles (ns) of one path: the daemon's (status interval or since start) and
/// `ftafm soak`'s receive latency.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// Samples in the histogram.
    pub count: u64,
    /// Median (ns).
    pub p50: u64,
    /// 90th percentile (ns).
    pub p90: u64,
    /// 99th percentile (ns).
    pub p99: u64,
    /// 99.9th percentile (ns).
    pub p999: u64,
    /// Largest (ns).
    pub max: u64,
}

impl LatencySummary {
    /// The percentiles under their Prometheus `quantile` labels (ns).
    pub fn quantiles(&self) -> [(&'static str, u64); 5] {
        [
            ("0.5", self.p50),
            ("0.9", self.p90),
            ("0.99", self.p99),
            ("0.999", self.p999),
            ("1", self.max),
        ]
    }

    /// Percentiles of `h` (ns); all zero when it is empty.
    pub fn from_histogram<T: hdrhistogram::Counter>(h: &Histogram<T>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        Self {
            count: h.len(),
            p50: h.value_at_quantile(0.5),
            p90: h.value_at_quantile(0.9),
            p99: h.value_at_quantile(0.99),
            p999: h.value_at_quantile(0.999),
            max: h.max(),
        }
    }
}

/// The daemon process's memory, from `/proc/self/status` (Linux only).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProcessMemory {
    /// Resident set size now (bytes, `VmRSS`).
    pub resident_bytes: u64,
    /// Largest resident set size so far (bytes, `VmHWM`).
    pub resident_peak_bytes: u64,
}

impl ProcessMemory {
    /// This process's memory now; `None` where `/proc/self/status` does not exist or does
    /// not say (not Linux).
    pub fn read() -> Option<Self> {
        std::fs::read_to_string("/proc/self/status")
            .ok()
            .as_deref()
            .and_then(Self::parse)
    }

    /// Reads `VmRSS` and `VmHWM` (in kB) of a `/proc/PID/status` text.
    pub fn parse(status: &str) -> Option<Self> {
        let kib = |key: &str| {
            status.lines().find_map(|l| {
                let rest = l.strip_prefix(key)?.strip_prefix(':')?.trim();
                let n: u64 = rest.strip_suffix("kB")?.trim().parse().ok()?;
                Some(n * 1024)
            })
        };
        let resident_bytes = kib("VmRSS")?;
        Some(Self {
            resident_bytes,
            resident_peak_bytes: kib("VmHWM").unwrap_or(resident_bytes),
        })
    }
}

/// One client's figures for `/metrics` and `status`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClientReport {
    /// The client's id (in the daemon's debug log too).
    pub id: u64,
    /// Data messages handed to its socket.
    pub written: u64,
    /// Data messages dropped for it (its queue was full).
    pub dropped: u64,
    /// Bytes the server holds for it now: its queued data messages (bounded by
    /// `/server/client_queue_bytes`) and its replies not yet taken by its socket (bounded
    /// by it too, apart).
    #[serde(default)]
    pub queued_bytes: u64,
    /// DSP done → handed to its socket, demodulator messages (ns).
    pub dsp_to_socket: LatencySummary,
    /// Synthesised → handed to its socket, demodulator messages (ns).
    pub synth_to_socket: LatencySummary,
}

/// One `status` message's content.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StatusReport {
    /// The settings epoch in force (each committed change adds one).
    pub epoch: u64,
    /// Photodiode sample rate (Hz).
    pub sample_rate: f64,
    /// Samples processed per wall-clock second over the last interval / sample rate.
    pub realtime_factor: f64,
    /// Whether the chain is paced by the wall clock.
    pub realtime: bool,
    /// Samples waiting in the ring.
    pub ring_fill: u64,
    /// Ring capacity (samples).
    pub ring_capacity: u64,
    /// Where the chain's samples come from (`/source/kind`): `"synth"` or `"stream"`.
    pub source: &'static str,
    /// Streamed samples waiting in the feed for the chain, and its capacity (samples); the
    /// stream's frames, gaps and drops are in `counters` (`stream_…`).
    pub stream_fill: u64,
    pub stream_capacity: u64,
    /// WebSocket clients connected.
    pub clients: u64,
    /// Messages dropped for slow clients, all clients and streams, since start.
    pub messages_dropped: u64,
    /// synth → DSP-done latency of demodulator frames.
    pub latency_synth_to_dsp: LatencySummary,
    /// synth → handed to every client's queue.
    pub latency_synth_to_send: LatencySummary,
    /// DSP done → handed to a client's socket, all clients.
    pub latency_dsp_to_socket: LatencySummary,
    /// synth → handed to a client's socket, all clients.
    pub latency_synth_to_socket: LatencySummary,
    /// The pipeline's counters.
    pub counters: CountersSnapshot,
    /// The daemon's resident memory; absent where the system does not say (not Linux).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory: Option<ProcessMemory>,
    /// How the real-time threads are scheduled.
    pub threads: Vec<Promotion>,
    /// The machine's longest stall in the interval (ns): how much later than asked a thread
    /// of the daemon that only naps 1 ms at a time woke up. Latency spikes that coincide
    /// with one were the machine's (other processes, the hypervisor), not the chain's.
    pub machine_stall_max_ns: u64,
    /// What the operating point means and the user should know, in words: demodulators out
    /// of band, an inversion harmonic replaced, a clipping photodiode signal. Empty when all
    /// is well.
    pub warnings: Vec<String>,
    /// The tapping regime the live orbit is in, `"free"`, `"attractive"` or `"repulsive"`
    /// (the branch it is on, as an approach curve names it: `crate::sweep::regime`), from
    /// the newest demodulator frame synthesised under the settings in force; `None` before
    /// one, or without a demodulator at harmonic 1.
    pub regime: Option<&'static str>,
    /// Every connected client: messages written to its socket and dropped for it, and the
    /// latency at its socket since it connected.
    pub clients_detail: Vec<ClientReport>,
    /// The PID units (`/pids/N`), by index: what each runs on and its latest update.
    pub pids: Vec<PidReport>,
    /// The outputs a PID unit holds away from their nodes (`"surface_distance"`,
    /// `"drive_frequency"`, `"drive_amplitude"`, `"drive2_frequency"`,
    /// `"drive2_amplitude"`): one runs on it, or one ran and left it where it put it, as a
    /// z piezo or an oscillator holds. A new value of the node (`/surface/distance`,
    /// `/drive/frequency`, `/drive/free_amplitude`, `/drive2/frequency`,
    /// `/drive2/free_amplitude`) takes it back; turning the second excitation off lets go of
    /// it too.
    pub pid_held: Vec<&'static str>,
}

/// One PID unit in `status`: its settings in force and its latest update.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PidReport {
    /// N of `/pids/N`.
    pub index: usize,
    /// `/pids/N/enable` in force.
    pub enable: bool,
    /// `/pids/N/input`: `"r"`, `"phase"`, `"x"` or `"y"`.
    pub input: &'static str,
    /// `/pids/N/harmonic`.
    pub harmonic: u32,
    /// `/pids/N/oscillator`: `"drive"` or `"drive2"`.
    pub oscillator: &'static str,
    /// `/pids/N/output`: `"surface_distance"`, `"drive_frequency"`, `"drive_amplitude"`,
    /// `"drive2_frequency"` or `"drive2_amplitude"`.
    pub output: &'static str,
    /// `/pids/N/setpoint` in force (the input's unit).
    pub setpoint: f64,
    /// The latest update the synthesiser made (its epoch says under which settings);
    /// `None` before the unit's first. A disabled unit keeps its last.
    pub latest: Option<crate::pipeline::PidUpdate>,
    /// A PLL's lock (a unit on the phase driving either excitation's frequency) after its
    /// latest update: acquired after [`crate::synth::PLL_LOCK_UPDATES`] updates in a row
    /// within [`crate::synth::PLL_LOCK_PHASE`] of the set-point and not limited, lost at
    /// the first that is not. `None` for other units and before the first update.
    pub locked: Option<bool>,
    /// A PLL's losses of lock since the pipeline started, each counted however brief
    /// (the synthesiser counts them at every update). `None` for other units and before
    /// the first update.
    pub lock_losses: Option<u64>,
    /// A unit on an excitation's frequency: its latest output less that excitation's
    /// `/drive/frequency` or `/drive2/frequency` (Hz), the frequency shift Δf (Δf₂).
    /// `None` for other units and before the first update.
    pub frequency_shift: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proc_status_memory_parses() {
        let text = "Name:\tftafm\nVmHWM:\t   33000 kB\nVmRSS:\t   28000 kB\nThreads:\t9\n";
        assert_eq!(
            ProcessMemory::parse(text),
            Some(ProcessMemory {
                resident_bytes: 28000 * 1024,
                resident_peak_bytes: 33000 * 1024,
            })
        );
        assert_eq!(ProcessMemory::parse("Name:\tx\n"), None);
        #[cfg(target_os = "linux")]
        assert!(ProcessMemory::read().unwrap().resident_bytes > 0);
    }
}
