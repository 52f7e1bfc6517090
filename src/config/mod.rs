//! Configuration: the embedded default (`config/default.toml`), overlays from files, and
//! validation with errors that name the key, the value and the allowed range.
//!
//! - [`settings`]: the typed [`Settings`] (SI units throughout).
//! - [`field`]: the nodes of the tree (`/sample/youngs_modulus` …): units, ranges,
//!   descriptions, typed reads and writes.
//! - [`registry`](mod@registry): the one list of nodes, lookup by path, the tables of the tree.
//! - [`nodes`]: `get`/`set`/`list` by path, with per-node checks.
//! - `relations`: checks between nodes (Nyquist, sample period, mode count, scope traces that
//!   must not overlap, the inversion's harmonics measured by enabled demodulators, the scan's
//!   pixel dwell time and pixel rate) and the engines not available yet.
//! - `indexed_table`: the index-keyed tables of the files (`[demods]`, `[inclusions]`).
//! - [`load`](mod@load): the default and overlay files.
//! - [`presets`]: real cantilevers and samples (`config/presets/`), overlays by name.
//! - [`error`]: [`NodeError`] and [`ConfigError`].
//!
//! See `docs/configuration.md` for every node.

pub mod error;
pub mod field;
mod indexed_table;
pub mod load;
pub mod nodes;
pub mod presets;
pub mod quantity;
pub mod range;
pub mod registry;
mod relations;
pub mod settings;

pub use error::{ConfigError, NodeError};
pub use field::{
    Field, Kind, MAX_ADC_BITS, MAX_ALLOWED_ORIGINS, MAX_CLIENT_QUEUE, MAX_CLIENT_QUEUE_BYTES,
    MAX_CLIENTS, MAX_CONTACT_SUBSTEPS, MAX_DSP_THREADS, MAX_FILTER_ORDER, MAX_HARMONIC,
    MAX_HOST_BYTES, MAX_INVERSION_AVERAGING, MAX_INVERSION_POINTS, MAX_MODES, MAX_ORIGIN_BYTES,
    MAX_PIXEL_RATE, MAX_SCAN_PIXELS, MAX_SCOPE_DECIMATION, MAX_SCOPE_LENGTH, MAX_SPECTRUM_SIZE,
    MAX_YOUNGS_MODULUS, MIN_CLIENT_QUEUE, MIN_CLIENT_QUEUE_BYTES, MIN_CONTACT_SUBSTEPS,
    MIN_INVERSION_HARMONIC, MIN_INVERSION_POINTS, MIN_PIXEL_PERIODS, MIN_RATE, MIN_SCAN_PIXELS,
    MIN_SCOPE_LENGTH, MIN_SPECTRUM_SIZE, TextEntry,
};
pub use load::{DEFAULT_TOML, default_settings, load, load_str, overlay_str, settings_toml};
pub use nodes::{NodeInfo, NodeSpec};
pub use presets::{PRESETS, Preset, PresetKind, load_with_presets, preset};
pub use range::{Bound, Range};
pub use registry::{node, registry, table_keys};
pub use settings::*;
