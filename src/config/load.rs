//! Loading settings: the embedded default (`config/default.toml`, the paper's silicon case)
//! and partial overlay files on top of it. Every key of an overlay goes through the same
//! per-node checks as the protocol's `set`; the checks between nodes run once the whole file
//! is applied, so a file may raise the sample rate and a harmonic together.

use std::path::Path;
use std::sync::OnceLock;

use serde_json::Value;

use super::error::{ConfigError, NodeError};
use super::kind::Kind;
use super::registry::{node, table_keys, toml_table_name};
use super::settings::{Settings, wide_u64};
use super::show::cut;
use super::spec::NodeSpec;

/// The embedded default configuration, `config/default.toml`.
pub const DEFAULT_TOML: &str = include_str!("../../config/default.toml");

/// The embedded default settings (the paper's silicon case). A unit test proves the
/// embedded file parses and validates, so this does not fail in a built binary.
pub fn default_settings() -> Settings {
    static DEFAULT: OnceLock<Settings> = OnceLock::new();
    DEFAULT
        .get_or_init(|| {
            parse_default().unwrap_or_else(|e| panic!("embedded config/default.toml: {e}"))
        })
        .clone()
}

/// The default file is complete, so it is read with serde (which insists on every field)
/// rather than as an overlay, and then validated.
fn parse_default() -> Result<Settings, String> {
    let settings: Settings = toml::from_str(DEFAULT_TOML).map_err(|e| e.to_string())?;
    settings.validate().map_err(|e| e.to_string())?;
    Ok(settings)
}

/// `settings` as a complete config file: every node, in the tables of
/// `config/default.toml`, which `--config` (and the protocol's `load_settings`) reads back
/// to the same settings.
pub fn settings_toml(settings: &Settings) -> Result<String, String> {
    let body = toml::to_string(settings).map_err(|e| format!("settings as TOML: {e}"))?;
    Ok(format!(
        "# ftafm {} settings: every node (docs/configuration.md). Run them with\n\
         # `ftafm --config FILE`, or load them into a running daemon (op load_settings).\n\n\
         {body}",
        env!("CARGO_PKG_VERSION")
    ))
}

/// Settings from the file at `path` laid over the embedded default, or the default itself
/// when `path` is `None`.
pub fn load(path: Option<&Path>) -> Result<Settings, ConfigError> {
    let Some(path) = path else {
        return Ok(default_settings());
    };
    let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Read {
        path: path.to_owned(),
        error,
    })?;
    load_str(&text, &path.display().to_string())
}

/// Settings from TOML text laid over the embedded default. `origin` names the text in
/// error messages (usually the file name).
pub fn load_str(overlay_toml: &str, origin: &str) -> Result<Settings, ConfigError> {
    overlay_str(default_settings(), overlay_toml, origin)
}

/// Settings from TOML text laid over `base`: each key present replaces that node, arrays
/// (like `/cantilever/q`) whole; everything else keeps its value from `base`. Then the
/// whole result is validated.
pub fn overlay_str(
    base: Settings,
    overlay_toml: &str,
    origin: &str,
) -> Result<Settings, ConfigError> {
    let table: toml::Table =
        overlay_toml
            .parse()
            .map_err(|e: toml::de::Error| ConfigError::Syntax {
                origin: origin.to_owned(),
                message: e.to_string().trim_end().to_owned(),
            })?;
    let mut settings = base;
    let mut written = Vec::new();
    apply_table(&mut settings, "", &table, origin, &mut written)?;
    let written: Vec<&str> = written.iter().map(String::as_str).collect();
    settings
        .derive_linked(&written)
        .map_err(|error| ConfigError::Invalid {
            origin: origin.to_owned(),
            error,
        })?;
    settings.validate().map_err(|error| ConfigError::Invalid {
        origin: origin.to_owned(),
        error,
    })?;
    Ok(settings)
}

/// Walks one TOML table whose node path is `prefix` (`""` at the top level).
fn apply_table(
    settings: &mut Settings,
    prefix: &str,
    table: &toml::Table,
    origin: &str,
    written: &mut Vec<String>,
) -> Result<(), ConfigError> {
    for (key, value) in table {
        let path = format!("{prefix}/{key}");
        if let Some(spec) = node(&path) {
            let invalid = |error: NodeError| ConfigError::Invalid {
                origin: origin.to_owned(),
                error,
            };
            // JSON, the representation `set` takes, has no NaN or infinity: refuse them
            // here, while the file's spelling (`nan`, `inf`) is still at hand.
            if has_non_finite(value) {
                return Err(invalid(spec.non_finite(&cut(&value.to_string()))));
            }
            settings
                .write_node(spec, &node_json(spec, value))
                .map_err(invalid)?;
            written.push(path);
        } else if let Some(keys) = table_keys(&path) {
            let toml::Value::Table(inner) = value else {
                return Err(ConfigError::NotATable {
                    origin: origin.to_owned(),
                    table: toml_table_name(&path),
                    path,
                    allowed: keys.to_vec(),
                });
            };
            apply_table(settings, &path, inner, origin, written)?;
        } else {
            return Err(ConfigError::UnknownKey {
                origin: origin.to_owned(),
                path,
                table: toml_table_name(prefix),
                allowed: table_keys(prefix).unwrap_or_default().to_vec(),
            });
        }
    }
    Ok(())
}

/// Whether a leaf value is or holds (in an array) a NaN or an infinity. Tables are left to
/// the type check, which refuses them for every node.
fn has_non_finite(value: &toml::Value) -> bool {
    match value {
        toml::Value::Float(x) => !x.is_finite(),
        toml::Value::Array(items) => items.iter().any(has_non_finite),
        _ => false,
    }
}

/// The JSON value `set` would receive for `value` of the node `spec`: [`to_json`], but an
/// integer node that goes beyond TOML's integers (`/synth/seed`) takes a larger value as the
/// string of its digits, as `settings` writes it.
fn node_json(spec: &NodeSpec, value: &toml::Value) -> Value {
    if let (Kind::Integer { max, .. }, toml::Value::String(text)) = (spec.kind, value)
        && i64::try_from(max).is_err()
        && let Some(n) = wide_u64::parse(text)
    {
        return Value::from(n);
    }
    to_json(value)
}

/// The JSON value `set` would receive for this TOML value. Datetimes become strings (and
/// are then refused by the type check); non-finite floats become null.
fn to_json(value: &toml::Value) -> Value {
    match value {
        toml::Value::String(s) => Value::from(s.as_str()),
        toml::Value::Integer(n) => Value::from(*n),
        toml::Value::Float(x) => Value::from(*x),
        toml::Value::Boolean(b) => Value::from(*b),
        toml::Value::Datetime(d) => Value::from(d.to_string()),
        toml::Value::Array(items) => Value::Array(items.iter().map(to_json).collect()),
        toml::Value::Table(table) => {
            Value::Object(table.iter().map(|(k, v)| (k.clone(), to_json(v))).collect())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_default_parses_and_validates() {
        let settings = parse_default().unwrap();
        assert_eq!(settings, default_settings());
        assert_eq!(settings.sample.youngs_modulus, 129e9);
        assert_eq!(settings.demods.len(), super::super::DEMODULATOR_COUNT);
    }

    #[test]
    fn the_default_read_as_an_overlay_is_the_default() {
        // The overlay walker accepts everything the complete file says, unchanged.
        assert_eq!(
            load_str(DEFAULT_TOML, "default.toml").unwrap(),
            default_settings()
        );
    }
}
