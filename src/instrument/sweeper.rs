//! The sweeper (`/sweeper/*`, the `sweep` stream): steps one node through a sweep's points
//! in simulated time, lets the cantilever and the lock-in settle at each, averages every
//! demodulator's output and sends a message per point; at the end a final message with
//! what the sweep shows (a tune's resonance, an approach curve's contact, jumps and
//! hysteresis), and the node is restored. The arithmetic is in [`crate::sweep`].

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use serde_json::{Map, Value, json};
use tokio::sync::mpsc;

use tokio::sync::watch;

use super::Control;
use super::force::{ForceLink, ForceOutcome};
use super::tap::{FrameTap, Tap};
use crate::config::{
    DEMODULATOR_COUNT, Oscillator, Settings, SweepDirection, SweepParameter, SweepScale,
    SweeperSettings,
};
use crate::pipeline::DemodFrame;
use crate::sweep::{self, Leg};

/// Longest wait for a demodulator frame (wall time) before a sweep gives up.
const FRAME_WAIT: Duration = Duration::from_secs(10);
/// Longest wait (wall time) at a point for the force estimator of its settings; past it the
/// point reports that it has no force estimate. The estimator is built at nice 10 (without
/// the builder's rests while a sweep waits), so a machine busy with other work can slow a
/// build from 0.5 s to over 10 s (seen under `stress-ng --cpu 2`); a minute means something
/// is wrong.
const FORCE_WAIT: Duration = Duration::from_secs(60);
/// Inaccuracy the automatic settling time allows for (relative).
const SETTLE_TO: f64 = 1e-3;
/// How far a tune lifts the surface, as a multiple of the largest free amplitude its points
/// drive: the tip's swing then stays clear of the surface by as much again, as an
/// instrument's auto-tune retracts so that the resonance it fits is the free lever's.
const RETRACT_CLEARANCE: f64 = 2.0;

/// While alive, the force builder knows a sweep waits for each point's estimate.
struct Awaiting<'a>(&'a ForceLink);

impl<'a> Awaiting<'a> {
    fn new(force: &'a ForceLink) -> Self {
        force.await_estimates(true);
        Self(force)
    }
}

impl Drop for Awaiting<'_> {
    fn drop(&mut self) {
        self.0.await_estimates(false);
    }
}

/// Counts sweeps since the daemon started: `sweep` in every message of one.
static SWEEPS: AtomicU64 = AtomicU64::new(0);

/// Where a sweep's messages go: the simulated time (s) and the synthesis clock (ns) of the
/// frame they follow, and the message's fields after its envelope (`stream`, `seq`, `t`).
pub(crate) type Publish = Box<dyn Fn(f64, u64, Map<String, Value>) + Send + Sync>;

/// What the sweeper uses: the control plane it steps the node through, the taps the hub
/// fills while a sweep runs, the force worker whose estimates it waits for, shutdown, and
/// where its messages go.
pub(crate) struct SweeperLinks {
    pub control: Arc<Control>,
    pub frames: Arc<FrameTap>,
    pub forces: Arc<Tap<ForceOutcome>>,
    pub force: Arc<ForceLink>,
    pub shutdown: watch::Receiver<bool>,
    pub publish: Publish,
}

/// Runs until shutdown: waits for `/sweeper/enable`, runs the sweep, waits again.
pub(crate) async fn run(links: SweeperLinks) {
    let Some(mut frames) = links.frames.take_receiver() else {
        return;
    };
    let Some(mut forces) = links.forces.take_receiver() else {
        return;
    };
    let mut changes = links.control.subscribe();
    let mut shutdown = links.shutdown.clone();
    loop {
        let current = links.control.current();
        if current.settings.sweeper.enable {
            if run_sweep(&links, current, &mut frames, &mut forces, &mut changes)
                .await
                .is_err()
            {
                return; // shutting down
            }
            continue;
        }
        tokio::select! {
            r = changes.changed() => if r.is_err() { return },
            _ = shutdown.changed() => return,
        }
    }
}

/// The simulated time (s) a point waits before averaging when `/sweeper/settling` is 0:
/// mode 1's ring-down and the slowest active demodulator filter's settling, to
/// [`SETTLE_TO`].
pub(crate) fn automatic_settling(s: &Settings) -> f64 {
    let ring = crate::model::cantilever(s)
        .map(|c| {
            let m = c.fundamental();
            sweep::ring_down(m.frequency, m.q, SETTLE_TO)
        })
        .unwrap_or(0.0);
    let filter = (0..DEMODULATOR_COUNT)
        .filter(|&i| s.demod_active(i))
        .map(|i| sweep::filter_settling(s.demods[i].order, s.demods[i].timeconstant, SETTLE_TO))
        .fold(0.0, f64::max);
    ring + filter
}

/// What a sweep measured at one point.
struct Measured {
    value: f64,
    leg: Leg,
    /// Per demodulator index: harmonic, oscillator, mean x, mean y (NaN when it gave
    /// nothing).
    demods: [(u32, Oscillator, f64, f64); DEMODULATOR_COUNT],
}

impl Measured {
    /// Mean x and y of the first demodulator that gave output at harmonic `harmonic` of
    /// the drive (one on /drive2 measures no harmonic of the tapping).
    fn at(&self, harmonic: u32) -> Option<(f64, f64)> {
        self.demods
            .iter()
            .find(|(h, o, x, _)| *h == harmonic && *o == Oscillator::Drive && x.is_finite())
            .map(|(_, _, x, y)| (*x, *y))
    }

    /// r of the first demodulator at `harmonic` of the drive.
    fn r_at(&self, harmonic: u32) -> Option<f64> {
        self.at(harmonic).map(|(x, y)| x.hypot(y))
    }

    /// The mean deflection (m): x of the first demodulator at harmonic 0, if one runs.
    fn mean_deflection(&self) -> Option<f64> {
        self.at(0).map(|(x, _)| x)
    }

    /// The phase (rad) of the first demodulator at `harmonic` of the drive.
    fn phase_at(&self, harmonic: u32) -> Option<f64> {
        self.at(harmonic).map(|(x, y)| y.atan2(x))
    }
}

/// The force estimates of one point: their sums, or why there are none.
#[derive(Default)]
struct ForcePoint {
    n: u32,
    max_force: f64,
    contact_time_ratio: f64,
    youngs_modulus: f64,
    /// Sums of the estimates' variances.
    variances: [f64; 3],
    error: Option<String>,
}

impl ForcePoint {
    /// Takes `o` if an estimator of `generation` or later made it from frames at or after
    /// `from` (s); returns whether the point has its answer (an estimate, or why none).
    fn take(&mut self, o: &ForceOutcome, generation: u64, from: f64) -> bool {
        match o {
            ForceOutcome::Estimate(g, e, _) if *g >= generation && e.t >= from => {
                self.n += 1;
                self.max_force += e.max_force;
                self.contact_time_ratio += e.contact_time_ratio;
                self.youngs_modulus += e.youngs_modulus;
                for (v, sigma) in self.variances.iter_mut().zip([
                    e.max_force_sigma,
                    e.contact_time_ratio_sigma,
                    e.youngs_modulus_sigma,
                ]) {
                    *v += sigma * sigma;
                }
                true
            }
            ForceOutcome::Failed(g, t, why) if *g >= generation && *t >= from => {
                self.error.get_or_insert_with(|| why.clone());
                true
            }
            ForceOutcome::Unavailable(g, why) if *g >= generation => {
                self.error.get_or_insert_with(|| why.clone());
                true
            }
            _ => false,
        }
    }

    fn json(&self) -> Value {
        if self.n == 0 {
            return json!({"estimates": 0, "error": self.error});
        }
        let n = f64::from(self.n);
        // Standard deviation of the mean of n independent estimates.
        let sigma = |i: usize| self.variances[i].sqrt() / n;
        json!({
            "estimates": self.n,
            "max_force": self.max_force / n,
            "max_force_sigma": sigma(0),
            "contact_time_ratio": self.contact_time_ratio / n,
            "contact_time_ratio_sigma": sigma(1),
            "youngs_modulus": self.youngs_modulus / n,
            "youngs_modulus_sigma": sigma(2),
        })
    }
}

/// How a sweep ended.
enum Outcome {
    Done,
    /// Ended from outside, and why: `/sweeper/enable` set false, a new request, the swept
    /// node or the physics changed by someone else.
    Aborted(String),
    Failed(String),
}

/// Why a sweep of request `request` that last committed `mine` must end, now that `now`
/// is in force (`None`: it runs on). A change the sweep did not make to what it measures
/// ends it: a new request (`/sweeper/*` written, a preset, whole settings), its swept node
/// written by someone else, or the physics it runs on changed.
fn interrupted(
    request: u64,
    mine: &Settings,
    now: &crate::instrument::Current,
    swept: &[String],
) -> Option<String> {
    let s = &now.settings;
    if now.sweep_request != request {
        return Some(if s.sweeper.enable {
            "a new sweep was requested (/sweeper/* written)".to_owned()
        } else {
            "/sweeper/enable was set false".to_owned()
        });
    }
    if let Some(p) = swept.iter().find(|p| s.get(p).ok() != mine.get(p).ok()) {
        return Some(format!("{p} was set by a client during the sweep"));
    }
    let table = |name: &str| !swept.iter().any(|p| p.starts_with(name));
    let physics = s.cantilever != mine.cantilever
        || s.tip != mine.tip
        || s.sample != mine.sample
        || s.adhesion != mine.adhesion
        || s.synth != mine.synth
        || s.noise != mine.noise
        || (table("/drive/") && s.drive != mine.drive)
        || (table("/surface/") && s.surface != mine.surface);
    physics.then(|| {
        "the settings the sweep measures changed during it (the cantilever, tip, sample, \
         drive, surface, noise or engine)"
            .to_owned()
    })
}

/// The values set at one point: the parameter, and for a tune the free amplitude that
/// keeps the base amplitude constant.
fn point_values(
    w: &SweeperSettings,
    value: f64,
    tune: Option<&(crate::physics::Cantilever, f64)>,
) -> Vec<(String, Value)> {
    let mut values = vec![(w.parameter.name().to_owned(), json!(value))];
    if let Some((cantilever, base)) = tune {
        let free = base * crate::model::free_response_per_base(cantilever, value);
        values.push(("/drive/free_amplitude".to_owned(), json!(free)));
    }
    values
}

/// The nodes a sweep of `w` changes, as they are before it: what it restores (with the
/// surface distance when a tune retracts the tip).
/// The enabled PID units' means over a point (`settings` its settings): per unit `index`,
/// `output`, `measurement`, `error` and `updates`, and for a unit on the drive frequency
/// `frequency_shift` (its mean output less `/drive/frequency`, Hz: FM-AFM's Δf).
fn pid_means(
    settings: &Settings,
    from: &[crate::synth::PidSums],
    to: &[crate::synth::PidSums],
) -> Vec<Value> {
    settings
        .pids
        .iter()
        .zip(from.iter().zip(to))
        .enumerate()
        .filter(|(_, (pid, _))| pid.enable)
        .filter_map(|(index, (pid, (from, to)))| {
            let (measurement, error, output, updates) = to.since(from)?;
            let mut unit = json!({
                "index": index,
                "output": output,
                "measurement": measurement,
                "error": error,
                "updates": updates,
            });
            if let Some(oscillator) = pid.output.frequency_of() {
                unit["frequency_shift"] = json!(output - settings.oscillator_frequency(oscillator));
            }
            Some(unit)
        })
        .collect()
}

fn restore_values(s: &Settings, w: &SweeperSettings, retract: bool) -> Vec<(String, Value)> {
    let mut values: Vec<(String, Value)> = match w.parameter {
        SweepParameter::DriveFrequency => vec![
            ("/drive/frequency".to_owned(), json!(s.drive.frequency)),
            (
                "/drive/free_amplitude".to_owned(),
                json!(s.drive.free_amplitude),
            ),
            ("/drive/follow_f1".to_owned(), json!(s.drive.follow_f1)),
        ],
        p => vec![(p.name().to_owned(), s.get(p.name()).unwrap_or(Value::Null))],
    };
    if retract {
        values.push(("/surface/distance".to_owned(), json!(s.surface.distance)));
    }
    values.push(("/sweeper/enable".to_owned(), json!(false)));
    values
}

/// Runs the sweep `settings.sweeper` describes. `Err` only when the daemon shuts down.
async fn run_sweep(
    links: &SweeperLinks,
    start: crate::instrument::Current,
    frames: &mut mpsc::Receiver<DemodFrame>,
    forces: &mut mpsc::Receiver<ForceOutcome>,
    changes: &mut tokio::sync::watch::Receiver<u64>,
) -> Result<(), ()> {
    let settings: &Settings = &start.settings;
    let request = start.sweep_request;
    let w = settings.sweeper.clone();
    let id = SWEEPS.fetch_add(1, Ordering::Relaxed) + 1;
    let points = sweep::points(
        w.start,
        w.stop,
        w.points as usize,
        w.scale == SweepScale::Log,
        w.direction != SweepDirection::Down,
        w.direction != SweepDirection::Up,
    );
    let settle = if w.settling > 0.0 {
        w.settling
    } else {
        automatic_settling(settings)
    };
    let tune = (w.parameter == SweepParameter::DriveFrequency)
        .then(|| crate::model::cantilever(settings).ok())
        .flatten()
        .map(|c| {
            let base = settings.drive.free_amplitude
                / crate::model::free_response_per_base(&c, settings.drive.frequency);
            (c, base)
        });
    let retract = tune
        .as_ref()
        .and_then(|(c, base)| retract_distance(settings, c, *base, &points));
    let restore = restore_values(settings, &w, retract.is_some());
    // The nodes the sweep writes (all but /sweeper/enable, which is restore's last).
    let swept: Vec<String> = restore
        .iter()
        .map(|(p, _)| p.clone())
        .filter(|p| p != "/sweeper/enable")
        .collect();
    // The settings of the sweep's own last commit: a difference from them is someone
    // else's change.
    let mut mine: Arc<Settings> = start.settings.clone();
    tracing::info!(
        sweep = id,
        parameter = w.parameter.name(),
        points = points.len(),
        settle_s = settle,
        "sweep started"
    );

    // The force estimates of each point (a tune is free of the surface: no force there).
    let force_off = if !settings.inversion.enable {
        Some("the inversion is off (/inversion/enable = false)")
    } else if w.parameter == SweepParameter::DriveFrequency {
        Some("not measured in a frequency sweep")
    } else {
        None
    };
    while frames.try_recv().is_ok() {}
    while forces.try_recv().is_ok() {}
    let dropped_before =
        links.frames.dropped.load(Ordering::Relaxed) + links.forces.dropped.load(Ordering::Relaxed);
    links.frames.set_active(true);
    links.forces.set_active(force_off.is_none());
    // Each point waits for its estimator: the builder does not rest between them, until
    // the sweep ends, however it ends.
    let _awaiting = force_off.is_none().then(|| Awaiting::new(&links.force));
    let mut shutdown = links.shutdown.clone();
    let mut measured: Vec<Measured> = Vec::with_capacity(points.len());
    let (mut t_last, mut t_synth_last) = (0.0, 0u64);
    let mut outcome = Outcome::Done;
    let mut point_epoch;
    'points: for (i, p) in points.iter().enumerate() {
        let mut values = point_values(&w, p.value, tune.as_ref());
        if let (0, Some(r)) = (i, &retract) {
            values.push(("/surface/distance".to_owned(), json!(r.distance)));
        }
        let paths: Vec<String> = values.iter().map(|(p, _)| p.clone()).collect();
        let (before, swept_now) = (mine.clone(), swept.clone());
        // Checked and written in one step under the writer's lock: no client's change can
        // slip between the check and the point's values.
        let change = links
            .control
            .change(format!("sweep point {i}"), move |c| {
                if let Some(why) = interrupted(request, &before, c, &swept_now) {
                    return Err(crate::instrument::ChangeError::Declined(why));
                }
                let mut next = Settings::clone(&c.settings);
                next.set_many(&values)?;
                Ok((next, Some(paths), ()))
            })
            .await;
        let t_set = match change {
            Err(crate::instrument::ChangeError::Declined(why)) => {
                outcome = Outcome::Aborted(why);
                break;
            }
            Ok(c) => {
                mine = c.settings;
                point_epoch = c.epoch;
                c.t.unwrap_or(t_last)
            }
            Err(e) => {
                outcome = Outcome::Failed(format!(
                    "{} = {} at point {i}: {}",
                    w.parameter.name(),
                    p.value,
                    e
                ));
                break;
            }
        };
        let from = t_set + settle;
        // Force outcomes of an estimator built for this point's settings (or later).
        let generation = links.force.requested();
        let mut force = ForcePoint::default();
        let mut force_done = force_off.is_some();
        let mut force_deadline = None;
        let mut sums = [(0u32, Oscillator::Drive, 0.0f64, 0.0f64, 0u32); DEMODULATOR_COUNT];
        let mut taken = 0;
        // The PID units' running sums the point's first and last averaged frames carry:
        // their means over the same stretch of the stream, to a block.
        let mut pids_from = None;
        let mut pids_to = None;
        while taken < w.averaging || !force_done {
            tokio::select! {
                f = frames.recv() => {
                    let Some(f) = f else { return Err(()) };
                    if f.t < from {
                        continue;
                    }
                    if taken < w.averaging {
                        if taken == 0 {
                            pids_from = Some(f.pids);
                        }
                        for v in f.values() {
                            let s = &mut sums[usize::from(v.index)];
                            *s = (v.harmonic, v.oscillator, s.2 + v.x, s.3 + v.y, s.4 + 1);
                        }
                        taken += 1;
                        if taken == w.averaging {
                            pids_to = Some(f.pids);
                        }
                        (t_last, t_synth_last) = (f.t, f.t_synth_ns);
                    } else if !force_done {
                        let deadline = *force_deadline.get_or_insert_with(|| Instant::now() + FORCE_WAIT);
                        if Instant::now() > deadline {
                            force.error = Some(format!(
                                "no force estimate within {} s", FORCE_WAIT.as_secs()
                            ));
                            force_done = true;
                        }
                    }
                }
                o = forces.recv(), if force_off.is_none() => {
                    let Some(o) = o else { return Err(()) };
                    force_done |= force.take(&o, generation, from);
                }
                r = changes.changed() => {
                    if r.is_err() {
                        return Err(());
                    }
                    if let Some(why) = interrupted(request, &mine, &links.control.current(), &swept) {
                        outcome = Outcome::Aborted(why);
                        break 'points;
                    }
                }
                _ = shutdown.changed() => return Err(()),
                _ = tokio::time::sleep(FRAME_WAIT) => {
                    outcome = Outcome::Failed(format!(
                        "no demodulator output for {} s at point {i}", FRAME_WAIT.as_secs()
                    ));
                    break 'points;
                }
            }
        }
        let mut demods = [(0u32, Oscillator::Drive, f64::NAN, f64::NAN); DEMODULATOR_COUNT];
        for (d, s) in demods.iter_mut().zip(&sums) {
            if s.4 > 0 {
                *d = (s.0, s.1, s.2 / f64::from(s.4), s.3 / f64::from(s.4));
            }
        }
        let m = Measured {
            value: p.value,
            leg: p.leg,
            demods,
        };
        let list: Vec<Value> = m
            .demods
            .iter()
            .enumerate()
            .filter(|(_, (_, _, x, _))| x.is_finite())
            .map(|(index, (h, o, x, y))| {
                json!({"index": index, "harmonic": h, "oscillator": o.name(), "x": x, "y": y,
                       "r": x.hypot(*y), "phase": y.atan2(*x)})
            })
            .collect();
        let mut fields = Map::new();
        fields.insert("sweep".into(), json!(id));
        fields.insert("request".into(), json!(request));
        fields.insert("epoch".into(), json!(point_epoch));
        fields.insert("parameter".into(), json!(w.parameter.name()));
        fields.insert("point".into(), json!(i));
        fields.insert("points".into(), json!(points.len()));
        fields.insert("leg".into(), json!(p.leg.name()));
        fields.insert("value".into(), json!(p.value));
        fields.insert(
            "progress".into(),
            json!((i + 1) as f64 / points.len() as f64),
        );
        if let Some((c, base)) = &tune {
            fields.insert(
                "free_amplitude".into(),
                json!(base * crate::model::free_response_per_base(c, p.value)),
            );
        }
        if let Some(phase) = m.phase_at(1) {
            fields.insert(
                "h1_phase_to_drive".into(),
                json!(sweep::phase_to_drive(phase)),
            );
        }
        if let Some(mean) = m.mean_deflection() {
            fields.insert("mean_deflection".into(), json!(mean));
        }
        if force_off.is_none() {
            fields.insert("force".into(), force.json());
        }
        if let (Some(from), Some(to)) = (&pids_from, &pids_to) {
            let units = pid_means(&mine, from, to);
            if !units.is_empty() {
                fields.insert("pids".into(), Value::Array(units));
            }
        }
        fields.insert("demods".into(), Value::Array(list));
        (links.publish)(t_last, t_synth_last, fields);
        measured.push(m);
    }
    links.frames.set_active(false);
    links.forces.set_active(false);

    // Restore each swept node that still holds the sweep's own value (one a client set
    // meanwhile keeps the client's), and turn the sweep off unless a new one was requested
    // meanwhile; retry while the chain is busy with an earlier change.
    let mut restored = Err(String::new());
    let mut kept: Vec<String> = Vec::new();
    for _ in 0..20 {
        let (values, last) = (restore.clone(), mine.clone());
        match links
            .control
            .change(format!("sweep {id}: restore"), move |c| {
                let (mut set, mut kept) = (Vec::new(), Vec::new());
                for (path, value) in values {
                    if path == "/sweeper/enable" {
                        if c.sweep_request == request {
                            set.push((path, value));
                        }
                    } else if c.settings.get(&path).ok() == last.get(&path).ok() {
                        set.push((path, value));
                    } else {
                        kept.push(path);
                    }
                }
                let mut next = Settings::clone(&c.settings);
                next.set_many(&set)?;
                Ok((next, Some(set.into_iter().map(|(p, _)| p).collect()), kept))
            })
            .await
        {
            Ok(c) => {
                kept = c.value;
                restored = Ok(());
                break;
            }
            Err(crate::instrument::ChangeError::Busy(_)) => {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            Err(e) => {
                restored = Err(e.to_string());
                break;
            }
        }
    }
    if let Err(why) = &restored {
        tracing::warn!(sweep = id, %why, "the swept node could not be restored");
        // Turn the sweep off at least, so it does not start over.
        let _ = links
            .control
            .change(format!("sweep {id}: off"), move |c| {
                let mut next = Settings::clone(&c.settings);
                if c.sweep_request == request {
                    next.sweeper.enable = false;
                }
                Ok((next, Some(vec!["/sweeper/enable".to_owned()]), ()))
            })
            .await;
    }

    let mut fields = Map::new();
    fields.insert("sweep".into(), json!(id));
    fields.insert("request".into(), json!(request));
    fields.insert("epoch".into(), json!(links.control.epoch()));
    fields.insert("parameter".into(), json!(w.parameter.name()));
    fields.insert("done".into(), json!(true));
    let (name, reason) = match &outcome {
        Outcome::Done => ("done", Value::Null),
        Outcome::Aborted(why) => ("aborted", json!(why)),
        Outcome::Failed(why) => ("failed", json!(why)),
    };
    fields.insert("outcome".into(), json!(name));
    fields.insert("reason".into(), reason);
    fields.insert("measured".into(), json!(measured.len()));
    fields.insert("points".into(), json!(points.len()));
    fields.insert("restored".into(), json!(restored.is_ok()));
    // Swept nodes a client set during the sweep: they keep the client's value.
    fields.insert("kept".into(), json!(kept));
    fields.insert(
        "frames_dropped".into(),
        json!(
            links.frames.dropped.load(Ordering::Relaxed)
                + links.forces.dropped.load(Ordering::Relaxed)
                - dropped_before
        ),
    );
    if let Some(why) = force_off {
        fields.insert("force".into(), json!(format!("off: {why}")));
    }
    if w.parameter == SweepParameter::DriveFrequency {
        fields.insert("tune".into(), tune_summary(&measured));
        fields.insert(
            "retracted".into(),
            retract.as_ref().map_or(Value::Null, Retract::json),
        );
    }
    if w.parameter == SweepParameter::SurfaceDistance {
        fields.insert("approach".into(), approach_summary(&measured, settings));
    }
    (links.publish)(t_last, t_synth_last, fields);
    tracing::info!(
        sweep = id,
        outcome = name,
        points = measured.len(),
        "sweep ended"
    );
    Ok(())
}

/// Where a tune puts the surface so that the tip swings free: the distance (m) and the one
/// it had before, which the tune restores.
struct Retract {
    distance: f64,
    from: f64,
    /// Whether the tip's largest swing stays below `distance` with the full clearance
    /// (false when the longest distance allowed is not enough).
    clear: bool,
}

impl Retract {
    fn json(&self) -> Value {
        json!({"distance": self.distance, "from": self.from, "clear": self.clear})
    }
}

/// The retract a tune of `points` needs: `None` when the surface already lies
/// [`RETRACT_CLEARANCE`] times the largest free amplitude of the tune's points away.
fn retract_distance(
    s: &Settings,
    cantilever: &crate::physics::Cantilever,
    base: f64,
    points: &[sweep::Point],
) -> Option<Retract> {
    let peak = points
        .iter()
        .map(|p| base * crate::model::free_response_per_base(cantilever, p.value))
        .fold(0.0, f64::max);
    let wanted = RETRACT_CLEARANCE * peak;
    if s.surface.distance >= wanted {
        return None;
    }
    let longest = crate::config::limits::LENGTH.max.value;
    Some(Retract {
        distance: wanted.min(longest),
        from: s.surface.distance,
        clear: wanted <= longest,
    })
}

/// A tune's fit of harmonic 1: f0 (Hz), Q, the detector's base amplitude (m) and the
/// phase against the drive (rad) measured nearest f0; `null` if it does not fit.
fn tune_summary(measured: &[Measured]) -> Value {
    let (f, r): (Vec<f64>, Vec<f64>) = measured
        .iter()
        .filter_map(|m| Some((m.value, m.r_at(1)?)))
        .unzip();
    let Some(fit) = sweep::fit_tune(&f, &r) else {
        return Value::Null;
    };
    let phase = measured
        .iter()
        .filter(|m| m.r_at(1).is_some())
        .min_by(|a, b| {
            (a.value - fit.f0)
                .abs()
                .total_cmp(&(b.value - fit.f0).abs())
        })
        .and_then(|m| m.phase_at(1));
    json!({"f0": fit.f0, "q": fit.q, "amplitude": fit.amplitude,
           "phase_to_drive_at_f0": phase.map(sweep::phase_to_drive)})
}

/// Each point's regime (`sweep::regime`) against the free lever's reading `free`.
fn regimes(measured: &[Measured], free: sweep::ApproachPoint) -> Vec<(Leg, f64, sweep::Regime)> {
    measured
        .iter()
        .filter_map(|m| {
            let p = sweep::ApproachPoint {
                r: m.r_at(1)?,
                phase: sweep::phase_to_drive(m.phase_at(1)?),
                mean: m.mean_deflection(),
            };
            Some((
                m.leg,
                m.value,
                sweep::regime(
                    p,
                    free,
                    sweep::FREE_DROP,
                    sweep::FREE_TWIST,
                    sweep::MEAN_FLOOR,
                ),
            ))
        })
        .collect()
}

/// An approach curve's contact onset per leg (the first distance, in the order measured,
/// where harmonic 1 falls 2 % below its free amplitude), jumps (consecutive points 10 %
/// apart, or in different regimes) with the regime on each side, each point's regime (free, attractive or
/// repulsive: the branch it is on) and hysteresis between the legs.
fn approach_summary(measured: &[Measured], settings: &Settings) -> Value {
    let regimes = sweep::free_point(settings).map_or_else(Vec::new, |free| regimes(measured, free));
    let regime_at = |l: Leg, v: f64| {
        regimes
            .iter()
            .find(|(leg, value, _)| *leg == l && *value == v)
            .map(|(_, _, r)| r.name())
    };
    let leg = |l: Leg| -> Vec<(f64, f64)> {
        measured
            .iter()
            .filter(|m| m.leg == l)
            .filter_map(|m| Some((m.value, m.r_at(1)?)))
            .collect()
    };
    let (up, down) = (leg(Leg::Up), leg(Leg::Down));
    // The free amplitude is read where the tip is farthest from the surface: each leg is
    // looked at from its largest distance down.
    let onset = |points: &[(f64, f64)]| -> Option<f64> {
        let mut p = points.to_vec();
        p.sort_by(|a, b| b.0.total_cmp(&a.0));
        let (v, r): (Vec<f64>, Vec<f64>) = p.into_iter().unzip();
        sweep::contact_onset(&v, &r, 3, 0.02)
    };
    // A jump: the amplitude's, or a change of regime between two points in contact (at
    // small amplitudes with adhesion, the phase jumps by a radian where the amplitude moves
    // by 1 %).
    let jumps = |l: Leg, points: &[(f64, f64)]| -> Vec<Value> {
        let (v, r): (Vec<f64>, Vec<f64>) = points.iter().copied().unzip();
        let mut found = sweep::jumps(&v, &r, 0.1);
        for (w, r) in v.windows(2).zip(r.windows(2)) {
            let (a, b) = (regime_at(l, w[0]), regime_at(l, w[1]));
            if a != b
                && a != Some("free")
                && b != Some("free")
                && !found.iter().any(|j| j.from == w[0])
            {
                found.push(sweep::Jump {
                    from: w[0],
                    to: w[1],
                    r_before: r[0],
                    r_after: r[1],
                });
            }
        }
        found.sort_by(|a, b| {
            let at = |x: f64| v.iter().position(|&y| y == x).unwrap_or(usize::MAX);
            at(a.from).cmp(&at(b.from))
        });
        found
            .into_iter()
            .map(|j| {
                json!({"leg": l.name(), "from": j.from, "to": j.to,
                       "r_before": j.r_before, "r_after": j.r_after,
                       "regime_before": regime_at(l, j.from),
                       "regime_after": regime_at(l, j.to)})
            })
            .collect()
    };
    let mut all_jumps = jumps(Leg::Up, &up);
    all_jumps.extend(jumps(Leg::Down, &down));
    json!({
        "contact_up": onset(&up),
        "contact_down": onset(&down),
        "jumps": all_jumps,
        "regimes": regimes
            .iter()
            .map(|(l, v, r)| json!({"leg": l.name(), "value": v, "regime": r.name()}))
            .collect::<Vec<_>>(),
        "hysteresis": sweep::hysteresis(&up, &down).map(|(rel, at)| json!({"max": rel, "at": at})),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_reads_the_drives_harmonics_past_a_demodulator_on_drive2() {
        // Demodulator 0 reads harmonic 1 of /drive2: the tune's and approach's harmonic 1
        // and mean are demodulator 1's and 2's, on the drive.
        let mut demods = [(0, Oscillator::Drive, f64::NAN, f64::NAN); DEMODULATOR_COUNT];
        demods[0] = (1, Oscillator::Drive2, 3.0, 4.0);
        demods[1] = (1, Oscillator::Drive, 0.0, 2.0);
        demods[2] = (0, Oscillator::Drive, 7.0, 0.0);
        demods[3] = (0, Oscillator::Drive2, 9.0, 0.0);
        let m = Measured {
            value: 0.0,
            leg: Leg::Up,
            demods,
        };
        assert_eq!(m.r_at(1), Some(2.0));
        assert_eq!(m.phase_at(1), Some(std::f64::consts::FRAC_PI_2));
        assert_eq!(m.mean_deflection(), Some(7.0));
        assert_eq!(m.r_at(2), None);
    }
}
