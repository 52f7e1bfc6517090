//! Errors of the node tree ([`NodeError`], the protocol's `get`/`set` failures) and of
//! config files ([`ConfigError`]). Every message names the key; value errors also name the
//! offending value and what is allowed.
//!
//! The messages are complete sentences that already include any underlying cause (the OS
//! error, the TOML parser's line and column), so `source()` is not used: printing the error
//! once says everything, and printing a chain would say it twice.

use std::borrow::Cow;
use std::path::PathBuf;

use thiserror::Error;

use super::registry;
use super::show::cut;

/// A multi-line message (the TOML parser's, which quotes the offending line) with each
/// line cut as [`cut`] does, and at most 12 lines.
fn cut_lines(text: &str) -> String {
    let mut lines: Vec<Cow<'_, str>> = text.lines().take(12).map(cut).collect();
    if text.lines().nth(12).is_some() {
        lines.push(Cow::Borrowed("…"));
    }
    lines.join("\n")
}

/// Why a node could not be read or written (`get`, `set`, or one key of a config file).
#[derive(Clone, Debug, PartialEq, Eq, Error)]
pub enum NodeError {
    /// No node has this path.
    #[error("{}", registry::unknown_path_message(path))]
    UnknownPath {
        /// The path asked for.
        path: String,
    },
    /// `list` found no node at or under this (well-formed) prefix.
    #[error(
        "no node at or under {}; {}",
        cut(path),
        registry::unknown_path_message(path)
    )]
    NothingUnder {
        /// The prefix asked for.
        path: String,
    },
    /// The node is fixed while the instrument runs; it can only be set in a config file.
    #[error(
        "{} is read-only at runtime: set it in a config file and restart",
        cut(path)
    )]
    ReadOnly {
        /// The node's path.
        path: String,
    },
    /// Wrong type, out of range, or inconsistent with other nodes.
    #[error("{message}")]
    InvalidValue {
        /// The node whose value is refused.
        path: String,
        /// The whole sentence: path, offending value, and what is allowed.
        message: String,
    },
}

impl NodeError {
    /// The node path the error is about.
    pub fn path(&self) -> &str {
        match self {
            NodeError::UnknownPath { path }
            | NodeError::NothingUnder { path }
            | NodeError::ReadOnly { path }
            | NodeError::InvalidValue { path, .. } => path,
        }
    }

    /// The WebSocket protocol's error code: `unknown_path`, `read_only` or `invalid_value`.
    pub fn code(&self) -> &'static str {
        match self {
            NodeError::UnknownPath { .. } | NodeError::NothingUnder { .. } => "unknown_path",
            NodeError::ReadOnly { .. } => "read_only",
            NodeError::InvalidValue { .. } => "invalid_value",
        }
    }
}

/// Why a configuration could not be loaded. `origin` is the file name (or whatever the caller
/// passed to [`super::load_str`]).
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config file {}: {error}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the OS said.
        error: std::io::Error,
    },
    /// The file is not valid TOML.
    #[error("{origin} is not valid TOML: {}", cut_lines(message))]
    Syntax {
        /// The file.
        origin: String,
        /// The TOML parser's message, with line and column.
        message: String,
    },
    /// A key that is no node and no table of the tree.
    #[error(
        "unknown key {} in {origin}; keys of {table}: {}",
        cut(path),
        registry::key_list(allowed)
    )]
    UnknownKey {
        /// The file.
        origin: String,
        /// The node path the key would have, e.g. `/sample/youngs_moduls`.
        path: String,
        /// The enclosing table as TOML writes it (`[sample]`), or `the top level`.
        table: String,
        /// The keys that table does have.
        allowed: Vec<String>,
    },
    /// A plain value where the tree has a table, e.g. `sample = 3`.
    #[error(
        "{} in {origin} is a table, not a value: write {table} with keys {}",
        cut(path),
        registry::key_list(allowed)
    )]
    NotATable {
        /// The file.
        origin: String,
        /// The table's path, e.g. `/sample`.
        path: String,
        /// The table as TOML writes it (`[sample]`).
        table: String,
        /// The keys of that table.
        allowed: Vec<String>,
    },
    /// A value refused by its node, or settings that are inconsistent once the file applies.
    #[error("{origin}: {error}")]
    Invalid {
        /// The file.
        origin: String,
        /// What the node said.
        error: NodeError,
    },
    /// `--preset` names no preset.
    #[error("unknown preset {name:?}; presets: {allowed} (`ftafm presets` describes them)")]
    UnknownPreset {
        /// The name given (cut short).
        name: String,
        /// The presets there are, comma-separated.
        allowed: String,
    },
}

impl ConfigError {
    /// The node path (or table path) the error is about, if it is about one.
    pub fn path(&self) -> Option<&str> {
        match self {
            ConfigError::Read { .. }
            | ConfigError::Syntax { .. }
            | ConfigError::UnknownPreset { .. } => None,
            ConfigError::UnknownKey { path, .. } | ConfigError::NotATable { path, .. } => {
                Some(path)
            }
            ConfigError::Invalid { error, .. } => Some(error.path()),
        }
    }
}
