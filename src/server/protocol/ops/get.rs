//! `get`: one node's value, or beside the settings tree a measured value: `/demods/N/sample`
//! reads demodulator N's newest output (as LabOne's `getSample` does), so a script need not
//! subscribe to a stream for one number. With `paths`, many of them in one request, read
//! from one version of the settings (a client's snapshot of everything is one round trip,
//! well inside the request rate limit).

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::config::DEMODULATOR_COUNT;
use crate::server::protocol::fields::{Fields, bad, describe, quote, required_path};
use crate::server::protocol::{ErrorCode, ProtocolError};

/// Most paths one `get` may read: every node (about 300) and every demodulator's sample.
pub const MAX_PATHS: usize = 1024;

/// One value, or several.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Get {
    /// One node or measured value (`path`).
    One {
        /// Node path, starting with `/`.
        path: String,
    },
    /// Several (`paths`), read together.
    Many {
        /// Node paths, each starting with `/`, in the request's order.
        paths: Vec<String>,
    },
}

impl Get {
    /// `paths` (an array of 1 to [`MAX_PATHS`] paths, no `path` beside it) when it is given
    /// and not `null`; else `path`, required, starting with `/`.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        if fields.get("paths").is_some_and(|v| !v.is_null()) {
            return many(fields);
        }
        Ok(Get::One {
            path: required_path(fields, "get")?,
        })
    }

    /// One: `path` and `value`; for a node also its `epoch` and its `warning` if it has one.
    /// Many: `values` (path → value), the `epoch` of the settings read, `warnings` (path →
    /// warning, for nodes that have one) and `no_data` (path → why, for measured values that
    /// do not exist now, whose value is `null`). A path that names nothing refuses the
    /// whole request (`unknown_path`, naming it).
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        match self {
            Get::One { path } => one(ctx, path),
            Get::Many { paths } => all(ctx, paths),
        }
    }
}

fn one(ctx: &Context<'_>, path: String) -> Result<Map<String, Value>, ProtocolError> {
    if is_measured(&path) {
        let value = measured(ctx, &path)?;
        return Ok(reply(json!({ "path": path, "value": value })));
    }
    let current = ctx.control.current();
    let value = current
        .settings
        .get(&path)
        .map_err(|e| ProtocolError::from(&e))?;
    let mut fields = json!({ "path": path, "value": value, "epoch": current.epoch });
    if let Some(warning) = current.settings.node_warning(&path) {
        fields["warning"] = Value::from(warning);
    }
    Ok(reply(fields))
}

fn all(ctx: &Context<'_>, paths: Vec<String>) -> Result<Map<String, Value>, ProtocolError> {
    // One version of the settings for every node, so the values agree with each other.
    let current = ctx.control.current();
    let mut values = Map::new();
    let mut warnings = Map::new();
    let mut no_data = Map::new();
    for path in paths {
        if is_measured(&path) {
            let value = match measured(ctx, &path) {
                Ok(value) => value,
                Err(e) if e.code == ErrorCode::NoData => {
                    no_data.insert(path.clone(), Value::from(e.message));
                    Value::Null
                }
                Err(e) => return Err(e),
            };
            values.insert(path, value);
            continue;
        }
        let value = current
            .settings
            .get(&path)
            .map_err(|e| ProtocolError::from(&e))?;
        if let Some(warning) = current.settings.node_warning(&path) {
            warnings.insert(path.clone(), Value::from(warning));
        }
        values.insert(path, value);
    }
    Ok(reply(json!({
        "values": values,
        "epoch": current.epoch,
        "warnings": warnings,
        "no_data": no_data,
    })))
}

/// `get` with `paths`: an array of 1 to [`MAX_PATHS`] strings starting with `/`, no `path`
/// beside it.
fn many(fields: &Fields) -> Result<Get, ProtocolError> {
    if fields.get("path").is_some_and(|p| !p.is_null()) {
        return Err(bad(
            "op \"get\" takes either \"path\" (one value) or \"paths\" (several), not both"
                .to_owned(),
        ));
    }
    let example = r#"["/drive/frequency", "/demods/0/sample"]"#;
    let list = match fields.get("paths") {
        Some(Value::Array(list)) if !list.is_empty() && list.len() <= MAX_PATHS => list,
        Some(Value::Array(list)) if list.is_empty() => {
            return Err(bad(format!(
                "field \"paths\" of op \"get\" is empty: give at least one path, e.g. {example}"
            )));
        }
        Some(Value::Array(list)) => {
            return Err(bad(format!(
                "field \"paths\" of op \"get\" has {} paths: at most {MAX_PATHS}",
                list.len()
            )));
        }
        Some(other) => {
            return Err(bad(format!(
                "field \"paths\" of op \"get\" must be an array of paths, e.g. {example}; got {}",
                describe(other)
            )));
        }
        None => unreachable!("many() is called only when \"paths\" is present"),
    };
    list.iter()
        .map(|entry| match entry {
            Value::String(path) if path.starts_with('/') => Ok(path.clone()),
            Value::String(path) => Err(bad(format!(
                "each entry of field \"paths\" of op \"get\" must start with \"/\", got {}",
                quote(path)
            ))),
            other => Err(bad(format!(
                "each entry of field \"paths\" of op \"get\" must be a string starting with \
                 \"/\", got {}",
                describe(other)
            ))),
        })
        .collect::<Result<Vec<_>, _>>()
        .map(|paths| Get::Many { paths })
}

impl<'de> Deserialize<'de> for Get {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}

/// The demodulator a `/demods/N/sample` path names, if it is one (N may be out of range).
fn demod_index(path: &str) -> Option<&str> {
    path.strip_prefix("/demods/")?
        .strip_suffix("/sample")
        .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Whether `path` names a measured value rather than a node of the settings tree.
fn is_measured(path: &str) -> bool {
    demod_index(path).is_some()
}

/// The newest value at a measured `path`: for `/demods/N/sample`, `{t, harmonic, x, y, r,
/// phase}` of demodulator N's newest output frame (t in s of simulated time, x, y, r in m,
/// phase in rad).
fn measured(ctx: &Context<'_>, path: &str) -> Result<Value, ProtocolError> {
    let n = demod_index(path)
        .and_then(|n| n.parse::<usize>().ok())
        .filter(|&n| n < DEMODULATOR_COUNT)
        .ok_or_else(|| {
            ProtocolError::new(
                ErrorCode::UnknownPath,
                format!(
                    "unknown measured value {path}: demodulators are /demods/0/sample … \
                     /demods/{}/sample",
                    DEMODULATOR_COUNT - 1
                ),
            )
        })?;
    let frame = ctx
        .latest_demods
        .lock()
        .ok()
        .and_then(|f| *f)
        .ok_or_else(|| {
            ProtocolError::new(
                ErrorCode::NoData,
                format!("{path}: the lock-in has produced no output yet; retry shortly"),
            )
        })?;
    let value = frame
        .values()
        .iter()
        .find(|v| usize::from(v.index) == n)
        .ok_or_else(|| {
            let why = ctx
                .control
                .settings()
                .node_warning(&format!("/demods/{n}/enable"))
                .unwrap_or_else(|| format!("demodulator {n} is disabled (/demods/{n}/enable)"));
            ProtocolError::new(ErrorCode::NoData, format!("{path} has no output: {why}"))
        })?;
    Ok(json!({
        "t": frame.t,
        "harmonic": value.harmonic,
        "oscillator": value.oscillator.name(),
        "x": value.x,
        "y": value.y,
        "r": value.r(),
        "phase": value.phase(),
    }))
}

#[cfg(test)]
mod tests {
    use super::{demod_index, is_measured};

    #[test]
    fn only_demodulator_sample_paths_are_measured() {
        assert_eq!(demod_index("/demods/3/sample"), Some("3"));
        assert_eq!(demod_index("/demods/99/sample"), Some("99"));
        assert!(is_measured("/demods/0/sample"));
        assert!(!is_measured("/demods/0/harmonic"));
        assert!(!is_measured("/demods//sample"));
        assert!(!is_measured("/demods/x/sample"));
        assert!(!is_measured("/demods/0/sample/x"));
    }
}
