//! Reads of the latest measured values by path, beside the settings tree: `get` of
//! `/demods/N/sample` answers demodulator N's newest output (as LabOne's `getSample` does),
//! so a script need not subscribe to a stream for one number.

use serde_json::{Value, json};

use super::protocol::{ErrorCode, ProtocolError};
use super::state::AppState;
use crate::config::DEMODULATOR_COUNT;

/// The demodulator a `/demods/N/sample` path names, if it is one (N may be out of range).
fn demod_index(path: &str) -> Option<&str> {
    path.strip_prefix("/demods/")?
        .strip_suffix("/sample")
        .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Whether `path` names a measured value rather than a node of the settings tree.
pub(crate) fn is_measured(path: &str) -> bool {
    demod_index(path).is_some()
}

/// The newest value at a measured `path`: for `/demods/N/sample`, `{t, harmonic, x, y, r,
/// phase}` of demodulator N's newest output frame (t in s of simulated time, x, y, r in m,
/// phase in rad).
pub(crate) fn read(state: &AppState, path: &str) -> Result<Value, ProtocolError> {
    let n = demod_index(path)
        .and_then(|n| n.parse::<usize>().ok())
        .filter(|&n| n < DEMODULATOR_COUNT)
        .ok_or_else(|| ProtocolError {
            code: ErrorCode::UnknownPath,
            message: format!(
                "unknown measured value {path}: demodulators are /demods/0/sample … \
                 /demods/{}/sample",
                DEMODULATOR_COUNT - 1
            ),
        })?;
    let frame = state
        .latest_demods
        .lock()
        .ok()
        .and_then(|f| *f)
        .ok_or_else(|| ProtocolError {
            code: ErrorCode::NoData,
            message: format!("{path}: the lock-in has produced no output yet; retry shortly"),
        })?;
    let value = frame
        .values()
        .iter()
        .find(|v| usize::from(v.index) == n)
        .ok_or_else(|| {
            let why = state
                .control
                .settings()
                .node_warning(&format!("/demods/{n}/enable"))
                .unwrap_or_else(|| format!("demodulator {n} is disabled (/demods/{n}/enable)"));
            ProtocolError {
                code: ErrorCode::NoData,
                message: format!("{path} has no output: {why}"),
            }
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
