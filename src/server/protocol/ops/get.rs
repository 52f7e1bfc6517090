//! `get`: one node's value, or beside the settings tree a measured value: `/demods/N/sample`
//! reads demodulator N's newest output (as LabOne's `getSample` does), so a script need not
//! subscribe to a stream for one number.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::config::DEMODULATOR_COUNT;
use crate::server::protocol::fields::{Fields, required_path};
use crate::server::protocol::{ErrorCode, ProtocolError};

/// One node's value.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Get {
    /// Node path, starting with `/`.
    pub path: String,
}

impl Get {
    /// `path`, required, starting with `/`.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        Ok(Get {
            path: required_path(fields, "get")?,
        })
    }

    /// `path` and `value`; for a node also its `epoch` and its `warning` if it has one.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        let path = self.path;
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
