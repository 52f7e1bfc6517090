//! Configuration: the embedded default (`config/default.toml`), overlays from files, and
//! validation with errors that name the key, the value and the allowed range.
//!
//! From the bottom up (each module uses only those above it in this list):
//! - [`quantity`], [`range`]: numbers as messages show them, and ranges with open or
//!   closed ends; `show`: keys and values cut short for messages.
//! - [`kind`]: what values a node takes, and a value checked for its type.
//! - [`limits`]: the most modes, harmonics, clients …, and the static range of each quantity.
//! - [`settings`]: the typed [`Settings`] (SI units throughout); `indexed_table`: the
//!   index-keyed tables of the files (`[demods]`, `[inclusions]`).
//! - [`field`]: the node table, every node declared once (path, unit, values, writable,
//!   description, the setting it reads and writes).
//! - [`spec`]: a node with everything static about it, as the registry holds it.
//! - [`registry`](mod@registry): the one list of nodes, lookup by path, the tables of the tree.
//! - [`error`]: [`NodeError`] and [`ConfigError`].
//! - `check`: one value against its node on its own (type, range, entries).
//! - `relations`: checks between nodes (Nyquist, sample period, mode count, scope traces that
//!   must not overlap, the inversion's harmonics measured by enabled demodulators, the scan's
//!   pixel dwell time and pixel rate).
//! - [`nodes`]: `get`/`set`/`list` by path.
//! - [`load`](mod@load): the default and overlay files.
//! - [`presets`]: real cantilevers and samples (`config/presets/`), overlays by name.
//!
//! Whether settings can run (does the tip tap, does the orbit exist) is the model's question
//! (`model::check`), never the schema's. See `docs/configuration.md` for every node.

mod check;
pub mod error;
pub mod field;
mod indexed_table;
pub mod kind;
pub mod limits;
pub mod load;
pub mod nodes;
pub mod presets;
pub mod quantity;
pub mod range;
pub mod registry;
mod relations;
pub mod settings;
mod show;
pub mod spec;

pub use error::{ConfigError, NodeError};
pub use field::Field;
pub use kind::{Kind, TextEntry};
pub use limits::{
    MAX_ADC_BITS, MAX_ALLOWED_ORIGINS, MAX_CLIENT_QUEUE, MAX_CLIENT_QUEUE_BYTES, MAX_CLIENTS,
    MAX_CONTACT_SUBSTEPS, MAX_DSP_THREADS, MAX_FILTER_ORDER, MAX_HARMONIC, MAX_HOST_BYTES,
    MAX_INVERSION_AVERAGING, MAX_INVERSION_POINTS, MAX_MODES, MAX_ORIGIN_BYTES, MAX_PIXEL_RATE,
    MAX_SCAN_PIXELS, MAX_SCOPE_DECIMATION, MAX_SCOPE_LENGTH, MAX_SPECTRUM_SIZE, MAX_YOUNGS_MODULUS,
    MIN_CLIENT_QUEUE, MIN_CLIENT_QUEUE_BYTES, MIN_CONTACT_SUBSTEPS, MIN_INVERSION_HARMONIC,
    MIN_INVERSION_POINTS, MIN_PIXEL_PERIODS, MIN_RATE, MIN_SCAN_PIXELS, MIN_SCOPE_LENGTH,
    MIN_SPECTRUM_SIZE,
};
pub use load::{DEFAULT_TOML, default_settings, load, load_str, overlay_str, settings_toml};
pub use nodes::NodeInfo;
pub use presets::{PRESETS, Preset, PresetKind, load_with_presets, preset};
pub use range::{Bound, Range};
pub use registry::{node, registry, table_keys};
pub use relations::PASSBAND_FRACTION;
pub use settings::*;
pub use spec::NodeSpec;
