//! ftafm: a real-time virtual instrument for Fourier-transform atomic force microscopy.
//!
//! Layers (each depends only on those before it): [`physics`] (pure maths of the paper)
//! and, beside it, [`control`] (pure maths of the closed loops: the PID),
//! [`config`] (typed settings), [`timebase`] and [`cpu`] (the phase words and the CPU's
//! features both real-time stages share),
//! [`dsp`] and [`synth`] (real-time blocks, meeting only through the ring), [`pipeline`],
//! the daemon ([`server`]), and the commands ([`cli`]).

pub mod analyse;
pub mod cli;
pub mod config;
pub mod control;
pub mod cpu;
pub mod dsp;
pub mod imaging;
pub mod instrument;
pub mod inversion;
pub mod model;
pub mod physics;
pub mod pipeline;
pub mod server;
pub mod sweep;
pub mod synth;
pub mod timebase;
