//! The request envelope: one text frame into a [`Request`], its `id` and its [`Op`].

use serde::Deserialize;
use serde_json::Value;

use super::fields::{Fields, bad, describe, quote};
use super::ops::{Op, Set, from_serde, repeated_values};
use super::{ErrorCode, ProtocolError};

/// One parsed request.
#[derive(Clone, Debug, PartialEq)]
pub struct Request {
    /// The client's `id`, echoed in the reply; `Null` when absent.
    pub id: Value,
    /// What it asks for.
    pub op: Op,
}

/// An example request for error messages.
const EXAMPLE: &str = r#"{"id":1,"op":"hello"}"#;

/// Parses one text frame. On failure returns the request's id if it could be read (else
/// `Null`) and the error.
///
/// Rules: the frame is one JSON object; `id` is any JSON value (absent → `Null`); `op` is a
/// string naming an op; fields the op does not use are ignored (forward compatibility);
/// optional fields (`path` of `list`, `format`) that are `null` count as absent. Paths must
/// start with `/`; whether the node exists and accepts the value is the node tree's job.
pub fn parse_request(text: &str) -> Result<Request, (Value, ProtocolError)> {
    let parsed: Value = serde_json::from_str(text).map_err(|e| {
        // A NaN, an Infinity or a number beyond f64 (`1e999`) is not JSON. Say so, and keep
        // the request's id so that a client matching replies by id gets its answer.
        if let Some((id, token)) = non_finite(text) {
            return (
                id,
                bad(format!(
                    "request has the non-finite number {token}: JSON numbers are finite (no \
                     NaN, Infinity or values beyond ±1.8e308); send a finite value"
                )),
            );
        }
        (
            Value::Null,
            bad(format!(
                "request is not valid JSON ({e}); send one object such as {EXAMPLE}"
            )),
        )
    })?;
    let Value::Object(fields) = parsed else {
        return Err((
            Value::Null,
            bad(format!(
                "a request must be a JSON object such as {EXAMPLE}, got {}",
                describe(&parsed)
            )),
        ));
    };
    let id = fields.get("id").cloned().unwrap_or(Value::Null);
    if let Err(error) = check_op(&fields) {
        return Err((id, error));
    }
    match Op::deserialize(Value::Object(fields)) {
        Ok(op @ Op::Set(Set::Many { .. })) => match repeated_values(text) {
            Some(error) => Err((id, error)),
            None => Ok(Request { id, op }),
        },
        Ok(op) => Ok(Request { id, op }),
        Err(error) => Err((id, from_serde(&error))),
    }
}

/// The tag: `op` is there, a string, and one of the ops' names.
fn check_op(fields: &Fields) -> Result<(), ProtocolError> {
    match fields.get("op") {
        None => Err(bad(format!(
            "request has no \"op\" field; ops: {}",
            op_list()
        ))),
        Some(Value::String(op)) if Op::NAMES.contains(&op.as_str()) => Ok(()),
        Some(Value::String(unknown)) => Err(ProtocolError::new(
            ErrorCode::UnknownOp,
            format!("unknown op {}; ops: {}", quote(unknown), op_list()),
        )),
        Some(other) => Err(bad(format!(
            "field \"op\" must be a string, one of {}; got {}",
            op_list(),
            describe(other)
        ))),
    }
}

fn op_list() -> String {
    Op::NAMES.join(", ")
}

/// If `text` is JSON but for non-finite numbers (bare `NaN`, `Infinity`, `-Infinity`, or a
/// literal beyond f64 like `1e999`), the request's id (`Null` if none) and the first such
/// token (cut short). Those tokens are replaced by `null` to read the rest.
fn non_finite(text: &str) -> Option<(Value, String)> {
    let bytes = text.as_bytes();
    let mut out: Vec<u8> = Vec::with_capacity(text.len());
    let mut first: Option<String> = None;
    let mut i = 0;
    let mut in_string = false;
    while i < bytes.len() {
        let c = bytes[i];
        if in_string {
            out.push(c);
            if c == b'\\' && i + 1 < bytes.len() {
                out.push(bytes[i + 1]);
                i += 2;
                continue;
            }
            if c == b'"' {
                in_string = false;
            }
            i += 1;
            continue;
        }
        if c == b'"' {
            in_string = true;
            out.push(b'"');
            i += 1;
            continue;
        }
        // A token of letters, digits, signs, dots and exponents.
        let start = i;
        while i < bytes.len()
            && (bytes[i].is_ascii_alphanumeric() || matches!(bytes[i], b'+' | b'-' | b'.'))
        {
            i += 1;
        }
        if i == start {
            out.push(c);
            i += 1;
            continue;
        }
        let token = &text[start..i];
        let bad_token = matches!(token, "NaN" | "Infinity" | "-Infinity" | "+Infinity")
            || token
                .parse::<f64>()
                .is_ok_and(|x| !x.is_finite() && !token.eq_ignore_ascii_case("inf"));
        if bad_token {
            first.get_or_insert_with(|| token.chars().take(24).collect());
            out.extend_from_slice(b"null");
        } else {
            out.extend_from_slice(token.as_bytes());
        }
    }
    let token = first?;
    let Value::Object(fields) = serde_json::from_slice::<Value>(&out).ok()? else {
        return None;
    };
    Some((fields.get("id").cloned().unwrap_or(Value::Null), token))
}
