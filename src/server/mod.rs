//! The daemon: HTTP, static files, WebSocket sessions, the protocol and the node tree.
//! It only reads frames and sends settings; it never runs DSP.

mod app;
mod assets;
mod build_budget;
mod follow;
mod force;
mod host;
mod hub;
mod image;
mod latency;
mod latest;
pub mod listen;
pub mod memory;
mod metrics;
pub mod protocol;
mod session;
mod state;
pub mod status;
mod sweeper;
mod tap;

pub use app::{ServerError, run, run_with};
pub use listen::ConnectionLimits;
