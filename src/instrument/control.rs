//! [`Control`]: the settings in force, their epoch, and the one path that changes them.
//!
//! Readers (`get`, `list`, `/healthz`, `/metrics`, the status tick, a new connection) take a
//! snapshot under a lock held for a pointer copy, never across work. Writers queue on an
//! asynchronous lock (a flood of `set`s waits as futures, not as threads) and do their work,
//! the schema's checks, the model's feasibility check and the pipeline's hand-over, on one
//! blocking thread at a time, off the async workers. A change is all or nothing: it commits
//! only once the model has accepted it and the pipeline has taken it up, and once started it
//! finishes even if the requester goes away, so no half-applied state is ever visible.

use std::sync::{Arc, OnceLock, RwLock};
use std::time::Duration;

use tokio::sync::{Mutex, watch};

use crate::config::{ConfigError, NodeError, Settings};
use crate::pipeline::{Counters, CountersSnapshot, Pipeline, PipelineError, RetiredPlans};

/// Longest a settings change waits to learn the sample it took effect at (a block is
/// 0.4 ms at 10 MS/s; only a synthesiser that cannot move, free-running with its DSP held,
/// takes this long).
const EFFECT_WAIT: Duration = Duration::from_secs(1);

/// Why a change was refused; nothing changed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChangeError {
    /// A node refused its value, or the settings are inconsistent or infeasible (the
    /// message names the nodes).
    #[error(transparent)]
    Node(#[from] NodeError),
    /// The chain is still taking up an earlier change; retry shortly.
    #[error("{0}")]
    Busy(String),
    /// The change needs a restart of the daemon (a node fixed while it runs).
    #[error("{0}")]
    ReadOnly(String),
    /// The proposer itself declined, after looking at the settings in force (e.g. a sweep's
    /// point once a client has ended the sweep); nothing changed.
    #[error("{0}")]
    Declined(String),
    /// The change could not be carried out (a bug, not the request's fault).
    #[error("{0}")]
    Internal(String),
}

impl From<ConfigError> for ChangeError {
    /// Settings text (a preset, `load_settings`) refused: the message names the text, the
    /// key and what is allowed.
    fn from(e: ConfigError) -> Self {
        ChangeError::Node(NodeError::InvalidValue {
            path: e.path().unwrap_or_default().to_owned(),
            message: e.to_string(),
        })
    }
}

/// The settings in force and what was derived from them, as one snapshot.
#[derive(Clone, Debug)]
pub struct Current {
    /// The settings in force.
    pub settings: Arc<Settings>,
    /// Their epoch: 0 at start, one more with every committed change. Every derived
    /// output carries the epoch it reflects.
    pub epoch: u64,
    /// Where the operating point leaves the model's range ([`crate::model::range_warnings`]),
    /// recomputed off the request path when the physics changes.
    pub range_warnings: Arc<Vec<String>>,
    /// The epoch of the last change that wrote a `/sweeper/*` node (or possibly any node:
    /// a preset, whole settings): a sweep's request, its id. A sweep runs for the request
    /// it started with; a newer request ends it.
    pub sweep_request: u64,
    /// The simulated time (s) from which the stream runs under these settings (0 for the
    /// first; `None` when the synthesiser did not say in time, or without a pipeline).
    pub t: Option<f64>,
}

/// A committed change as its followers see it (the force estimator, the images, the
/// sweeper): called in commit order, on the change's thread, before the requester hears of
/// it, so nothing derived from the old settings is presented as current after the reply.
pub struct Committed<'a> {
    /// The settings before the change.
    pub previous: &'a Settings,
    /// The settings now.
    pub settings: &'a Arc<Settings>,
    /// The change's epoch.
    pub epoch: u64,
    /// The simulated time (s) from which the chain runs them (`None` without a pipeline or
    /// if the synthesiser did not get there in time).
    pub t: Option<f64>,
    /// The nodes the change wrote (`None`: possibly any, e.g. a preset or whole settings).
    pub paths: Option<&'a [String]>,
}

impl Committed<'_> {
    /// Whether the change may have written a node for which `affects` holds.
    pub fn touched(&self, affects: impl Fn(&str) -> bool) -> bool {
        self.paths
            .is_none_or(|paths| paths.iter().any(|p| affects(p)))
    }
}

/// What a committed change answers its requester.
#[derive(Debug)]
pub struct Changed<R> {
    /// What the change's function returned (e.g. the values as applied).
    pub value: R,
    /// The change's epoch.
    pub epoch: u64,
    /// The simulated time (s) it took effect, if known.
    pub t: Option<f64>,
    /// The settings now.
    pub settings: Arc<Settings>,
}

/// A change's proposal: the next settings, the nodes it writes (`None`: possibly any) and
/// what to answer.
pub type Proposal<R> = (Settings, Option<Vec<String>>, R);

type Follower = Box<dyn Fn(&Committed<'_>) + Send + Sync>;

/// What only the writer touches.
struct Writer {
    pipeline: Option<Pipeline>,
    /// The epoch of the last commit (the pipeline's when there is one).
    epoch: u64,
}

/// The settings in force, their epoch, and the only writer of both ([`Control::change`]).
pub struct Control {
    current: RwLock<Current>,
    writer: Arc<Mutex<Writer>>,
    /// The pipeline's counters, readable without the writer (`/healthz`, `/metrics`).
    counters: Option<Arc<Counters>>,
    epochs: watch::Sender<u64>,
    followers: OnceLock<Follower>,
}

impl Control {
    /// The control plane of `settings` (already checked by the schema and the model) run by
    /// `pipeline` (`None`: settings only, e.g. in tests).
    pub fn new(settings: Settings, pipeline: Option<Pipeline>) -> Self {
        let range_warnings = Arc::new(crate::model::range_warnings(&settings));
        let counters = pipeline.as_ref().map(Pipeline::counters_handle);
        Self {
            current: RwLock::new(Current {
                settings: Arc::new(settings),
                epoch: 0,
                range_warnings,
                sweep_request: 0,
                t: Some(0.0),
            }),
            writer: Arc::new(Mutex::new(Writer { pipeline, epoch: 0 })),
            counters,
            epochs: watch::channel(0).0,
            followers: OnceLock::new(),
        }
    }

    /// Sets what follows every committed change (once; later calls are ignored).
    pub fn set_followers(&self, f: impl Fn(&Committed<'_>) + Send + Sync + 'static) {
        let _ = self.followers.set(Box::new(f));
    }

    /// The settings in force and what was derived from them.
    pub fn current(&self) -> Current {
        match self.current.read() {
            Ok(c) => c.clone(),
            Err(poisoned) => poisoned.into_inner().clone(),
        }
    }

    /// The settings in force.
    pub fn settings(&self) -> Arc<Settings> {
        self.current().settings
    }

    /// The epoch of the settings in force.
    pub fn epoch(&self) -> u64 {
        self.current().epoch
    }

    /// Wakes on every committed change, with its epoch.
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.epochs.subscribe()
    }

    /// The pipeline's counters now (zero without a pipeline).
    pub fn counters(&self) -> Option<CountersSnapshot> {
        self.counters.as_ref().map(|c| c.snapshot())
    }

    /// Each PID unit's latest update (`None` before its first, and without a pipeline).
    pub fn pid_updates(&self) -> [Option<crate::pipeline::PidUpdate>; crate::config::PID_COUNT] {
        std::array::from_fn(|unit| self.counters.as_ref().and_then(|c| c.pids().latest(unit)))
    }

    /// Has the synthesiser queue every PID update for the `pids` stream, or stop.
    pub fn stream_pid_updates(&self, on: bool) {
        if let Some(c) = &self.counters {
            c.pids().set_streaming(on);
        }
    }

    /// The outputs a PID unit holds away from their nodes (empty without a pipeline).
    pub fn pid_held(&self) -> Vec<crate::config::PidTarget> {
        self.counters
            .as_ref()
            .map_or_else(Vec::new, |c| c.pids().held())
    }

    /// The plans the real-time threads handed back, to be freed here; empty while a change
    /// holds the pipeline (they wait for the next call).
    pub fn take_retired(&self) -> Option<RetiredPlans> {
        let mut writer = self.writer.try_lock().ok()?;
        writer.pipeline.as_mut().map(Pipeline::take_retired)
    }

    /// The one write path. `propose` turns the settings in force (and their epoch: it runs
    /// under the writer's lock, so what it reads is what it replaces) into the next ones (the
    /// schema's checks are its job: `Settings::set`, `overlay_str`); then the model checks
    /// they can run ([`crate::model::check`], bounded in time), the pipeline takes them up at
    /// one sample boundary, the followers hear of it and the new settings and epoch are
    /// published. `what` names the change in errors. On error nothing changed.
    ///
    /// Changes are serialised; waiting ones cost no thread. Once started on its blocking
    /// thread a change completes even if the returned future is dropped.
    pub async fn change<R: Send + 'static>(
        self: &Arc<Self>,
        what: String,
        propose: impl FnOnce(&Current) -> Result<Proposal<R>, ChangeError> + Send + 'static,
    ) -> Result<Changed<R>, ChangeError> {
        let writer = self.writer.clone().lock_owned().await;
        let control = self.clone();
        tokio::task::spawn_blocking(move || control.commit(writer, &what, propose))
            .await
            .map_err(|_| ChangeError::Internal("the settings task failed".to_owned()))?
    }

    /// [`change`](Self::change) for callers without a runtime (start-up, tests).
    pub fn change_blocking<R>(
        &self,
        what: &str,
        propose: impl FnOnce(&Current) -> Result<Proposal<R>, ChangeError>,
    ) -> Result<Changed<R>, ChangeError> {
        let writer = self.writer.clone().blocking_lock_owned();
        self.commit(writer, what, propose)
    }

    fn commit<R>(
        &self,
        mut writer: tokio::sync::OwnedMutexGuard<Writer>,
        what: &str,
        propose: impl FnOnce(&Current) -> Result<Proposal<R>, ChangeError>,
    ) -> Result<Changed<R>, ChangeError> {
        let before = self.current();
        let (next, paths, value) = propose(&before)?;
        let committed_paths = paths.as_deref();
        // The orbit depends on the physics' nodes only: a change that leaves them as they
        // were keeps its verdict (at a high Q a solve takes up to half a second).
        let physics = committed_paths.is_none_or(|p| p.iter().any(|p| affects_physics(p)));
        // The model's refusal names the change it refuses, as the schema's does.
        let named = |e: NodeError| match e {
            NodeError::InvalidValue { path, message } => NodeError::InvalidValue {
                path,
                message: format!("{what}: {message}"),
            },
            other => other,
        };
        let range_warnings = if physics {
            Arc::new(crate::model::check(&next).map_err(named)?.range_warnings)
        } else {
            crate::model::check_tune(&next).map_err(named)?;
            crate::model::check_pids(&next).map_err(named)?;
            before.range_warnings.clone()
        };
        let (epoch, t) = match writer.pipeline.as_mut() {
            Some(p) => {
                let written = crate::config::PidTarget::written(committed_paths);
                let epoch = p
                    .apply_writing(&next, written)
                    .map_err(|e| pipeline_error(e, what))?;
                let t = p
                    .effective_index(epoch, EFFECT_WAIT)
                    .map(|index| index as f64 / next.synth.sample_rate);
                (epoch, t)
            }
            None => (writer.epoch + 1, None),
        };
        writer.epoch = epoch;
        let settings = Arc::new(next);
        let sweep_request =
            if committed_paths.is_none_or(|p| p.iter().any(|p| p.starts_with("/sweeper/"))) {
                epoch
            } else {
                before.sweep_request
            };
        if let Some(follow) = self.followers.get() {
            follow(&Committed {
                previous: &before.settings,
                settings: &settings,
                epoch,
                t,
                paths: committed_paths,
            });
        }
        let next = Current {
            settings: settings.clone(),
            epoch,
            range_warnings,
            sweep_request,
            t,
        };
        match self.current.write() {
            Ok(mut c) => *c = next,
            Err(poisoned) => *poisoned.into_inner() = next,
        }
        self.epochs.send_replace(epoch);
        drop(writer);
        Ok(Changed {
            value,
            epoch,
            t,
            settings,
        })
    }

    /// Stops the pipeline (after any change in flight) and returns its final counters.
    pub async fn stop(self: &Arc<Self>) -> Option<CountersSnapshot> {
        let pipeline = self.writer.lock().await.pipeline.take()?;
        tokio::task::spawn_blocking(move || pipeline.stop())
            .await
            .ok()
    }
}

/// Whether a change of `path` moves the operating point (the physics the model checks).
pub fn affects_physics(path: &str) -> bool {
    [
        "/cantilever",
        "/tip",
        "/sample",
        "/drive",
        "/surface",
        "/adhesion",
    ]
    .iter()
    .any(|p| path.starts_with(p))
}

/// A pipeline's refusal; `what` names the change.
fn pipeline_error(e: PipelineError, what: &str) -> ChangeError {
    match e {
        PipelineError::Busy => ChangeError::Busy(format!("{what}: {e}; retry shortly")),
        PipelineError::Restart(_) => ChangeError::ReadOnly(format!("{what}: {e}")),
        other => ChangeError::Node(NodeError::InvalidValue {
            path: what.split(" = ").next().unwrap_or(what).to_owned(),
            message: format!("{what}: {other}"),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::default_settings;
    use serde_json::json;

    fn set(
        path: &'static str,
        value: serde_json::Value,
    ) -> impl FnOnce(&Current) -> Result<Proposal<()>, ChangeError> {
        move |c| {
            let mut next = (*c.settings).clone();
            next.set(path, &value)?;
            Ok((next, Some(vec![path.to_owned()]), ()))
        }
    }

    #[test]
    fn a_change_commits_with_a_new_epoch_and_a_refusal_changes_nothing() {
        let control = Control::new(default_settings(), None);
        assert_eq!(control.epoch(), 0);
        let c = control
            .change_blocking("t", set("/surface/distance", json!(18e-9)))
            .unwrap();
        assert_eq!(c.epoch, 1);
        assert_eq!(control.epoch(), 1);
        assert_eq!(control.settings().surface.distance, 18e-9);
        let before = control.settings();
        let err = control
            .change_blocking("t", set("/surface/distance", json!(-1.0)))
            .unwrap_err();
        assert!(err.to_string().contains("/surface/distance"), "{err}");
        assert_eq!(control.epoch(), 1);
        assert_eq!(*control.settings(), *before);
    }

    /// The values that spun the solver for minutes under the settings lock (Q = 1e7 with a
    /// 1 µm free amplitude) are decided within the solver's transient budget.
    #[test]
    fn a_high_q_orbit_is_decided_within_the_budget() {
        let control = Control::new(default_settings(), None);
        let c = control
            .change_blocking("t", |c| {
                let mut next = (*c.settings).clone();
                next.set_many(&[
                    ("/cantilever/q".to_owned(), json!([1e7])),
                    ("/drive/free_amplitude".to_owned(), json!(1e-6)),
                ])?;
                Ok((next, None, ()))
            })
            .unwrap();
        assert_eq!((c.epoch, control.settings().cantilever.q[0]), (1, 1e7));
    }

    #[test]
    fn followers_see_each_commit_in_order() {
        let control = Control::new(default_settings(), None);
        let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
        let s = seen.clone();
        control.set_followers(move |c| {
            s.lock()
                .unwrap()
                .push((c.epoch, c.touched(affects_physics)));
        });
        control
            .change_blocking("t", set("/surface/distance", json!(19e-9)))
            .unwrap();
        control
            .change_blocking("t", set("/scope/length", json!(2048)))
            .unwrap();
        assert_eq!(*seen.lock().unwrap(), vec![(1, true), (2, false)]);
    }
}
