//! Configuration: the embedded default (`config/default.toml`), overlays from files, and
//! validation with errors that name the key, the value and the allowed range.

mod settings;

pub use settings::*;
