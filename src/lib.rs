//! ftafm: a real-time virtual instrument for Fourier-transform atomic force microscopy.
//!
//! Layers (each depends only on those before it): [`physics`] (pure maths of the paper),
//! [`config`] (typed settings), [`dsp`] (real-time blocks), then the report and the daemon.

pub mod bench;
pub mod config;
pub mod dsp;
pub mod imaging;
pub mod inversion;
pub mod model;
pub mod paper;
pub mod physics;
pub mod pipeline;
pub mod scan;
pub mod server;
pub mod soak;
pub mod synth;
