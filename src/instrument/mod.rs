//! The control plane, between the real-time chain and the transport: [`Control`] owns the
//! settings and their epoch and is their only writer; everything that derives outputs from
//! the chain's frames follows its commits and stamps what it makes with the epoch it
//! reflects. Uses the schema (`config`), the model and the pipeline; nothing here knows of
//! WebSockets.

pub mod control;

pub use control::{ChangeError, Changed, Committed, Control, Current, Proposal, affects_physics};
