//! `ftafm analyse`: the lock-in bank, spectrum and force inversion of the daemon on a
//! recorded photodiode signal, offline, streamed from the file.
//!
//! - [`reader`]: the formats (NumPy, WAV, raw), read in pieces;
//! - [`reference`]: the reference's frequency and phase measured from samples;
//! - [`run`]: the analysis and its outputs;
//! - [`npy`]: the `.npy` header parse and a streaming writer;
//! - [`record`]: the synthesiser's own signal to a file, for the round trip.

pub mod npy;
pub mod reader;
pub mod record;
pub mod reference;
pub mod run;

pub use reader::{Format, Source};
pub use run::{
    Opened, Options, Output, Sidecar, Summary, analyse, analyse_with, open, sidecar_path,
};
