//! Closed-loop control as pure maths: the discrete PID controller the real-time chain's
//! loops (`/pids/N/*`, LabOne's shape) are built from. No threads, no I/O, no allocation
//! once built; a layer beside `physics`, depending on nothing else in the crate.
//!
//! The PID runs as a library unit: it is not yet wired into the live signal chain.

pub mod pid;

pub use pid::{Pid, PidError, PidSettings};
