//! The control plane, between the real-time chain and the transport: [`Control`] owns the
//! settings and their epoch and is their only writer; everything that derives outputs from
//! the chain's frames follows its commits and stamps what it makes with the epoch it
//! reflects. Uses the schema (`config`), the model, the inversion, the imaging and the
//! pipeline; nothing here knows of WebSockets.
//!
//! - [`control`]: the settings, their epoch and `change()`, their one writer.
//! - `force`: the force stream's worker and its estimator builder; `image`: the image
//!   stream's worker. Both follow the commits and stamp their outputs with the epoch.
//! - `sweeper`: steps a node through a sweep's points as a client of `change()`, each sweep
//!   keyed by the request that started it; `tap`: what the hub hands a running sweep.
//! - `bimodal`: the bimodal AM-FM estimate from a frame and mode 2's PLL, per epoch.
//! - [`unit_loop`]: the loop a live PID unit closes, as the advisor models it.
//! - `build_budget`: the CPU those rebuilds may take; `latest`: the slot that keeps only the
//!   newest settings to build for.

pub(crate) mod bimodal;
mod build_budget;
pub mod control;
pub(crate) mod force;
pub(crate) mod image;
mod latest;
pub(crate) mod sweeper;
pub(crate) mod tap;
pub mod unit_loop;

pub use control::{ChangeError, Changed, Committed, Control, Current, Proposal, affects_physics};
