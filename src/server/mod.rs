//! The daemon: HTTP, static files, WebSocket sessions, the protocol and the node tree.
//! It only reads frames and sends settings; it never runs DSP.

mod app;
mod assets;
mod follow;
mod host;
mod hub;
mod latency;
pub mod listen;
pub mod memory;
mod metrics;
pub mod protocol;
mod session;
mod state;
pub mod status;

pub use app::{ServerError, run, run_with};
pub use listen::ConnectionLimits;
