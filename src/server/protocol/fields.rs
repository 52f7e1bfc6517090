//! Reading a request's fields, as the ops share it: the fields an op's parse gets, the
//! readers of fields several ops take (`path`, `stream`), and the wording of their errors,
//! which names the field, the op, what was given and what is allowed.

use serde_json::{Map, Value};

use super::{ErrorCode, ProtocolError, StreamKind};

/// A request's fields but `op` (its tag): what an op's parse reads. Fields the op does not
/// use are ignored (forward compatibility).
pub type Fields = Map<String, Value>;

/// Longest rendering of a client's value quoted back in an error message (bytes).
const MAX_QUOTED: usize = 60;

/// `field "path"` of `op`, required: a string starting with `/` (`null` counts as absent).
pub(super) fn required_path(fields: &Fields, op: &str) -> Result<String, ProtocolError> {
    match fields.get("path") {
        None | Some(Value::Null) => Err(bad(format!(
            "op \"{op}\" needs field \"path\", a node path starting with \"/\" such as \
             \"/drive/frequency\""
        ))),
        Some(value) => check_path(value, op),
    }
}

/// `field "path"` of `op`, optional (absent or `null`: `None`).
pub(super) fn optional_path(fields: &Fields, op: &str) -> Result<Option<String>, ProtocolError> {
    match fields.get("path") {
        None | Some(Value::Null) => Ok(None),
        Some(value) => check_path(value, op).map(Some),
    }
}

fn check_path(value: &Value, op: &str) -> Result<String, ProtocolError> {
    match value {
        Value::String(path) if path.starts_with('/') => Ok(path.clone()),
        Value::String(path) => Err(bad(format!(
            "field \"path\" of op \"{op}\" must start with \"/\" (such as \"/drive/frequency\"), \
             got {}",
            quote(path)
        ))),
        other => Err(bad(format!(
            "field \"path\" of op \"{op}\" must be a string starting with \"/\", got {}",
            describe(other)
        ))),
    }
}

/// `field "stream"` of `op`, required: a stream's name (else `unknown_stream`).
pub(super) fn stream(fields: &Fields, op: &str) -> Result<StreamKind, ProtocolError> {
    match fields.get("stream") {
        None | Some(Value::Null) => Err(bad(format!(
            "op \"{op}\" needs field \"stream\", one of {}",
            StreamKind::name_list()
        ))),
        Some(Value::String(name)) => StreamKind::from_name(name).ok_or_else(|| {
            ProtocolError::new(
                ErrorCode::UnknownStream,
                format!(
                    "unknown stream {}; streams: {}",
                    quote(name),
                    StreamKind::name_list()
                ),
            )
        }),
        Some(other) => Err(bad(format!(
            "field \"stream\" of op \"{op}\" must be a string, one of {}; got {}",
            StreamKind::name_list(),
            describe(other)
        ))),
    }
}

/// A `bad_request` with this message.
pub(super) fn bad(message: String) -> ProtocolError {
    ProtocolError::new(ErrorCode::BadRequest, message)
}

/// `a number (3)`, `an array ([1,2])`, `null`…, shortened for long values.
pub(super) fn describe(value: &Value) -> String {
    let kind = match value {
        Value::Null => return "null".to_owned(),
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    };
    let text = value.to_string();
    format!("{kind} ({})", shorten(&text))
}

/// A client's string quoted as JSON, shortened for long strings.
pub(super) fn quote(text: &str) -> String {
    shorten(&Value::from(text).to_string())
}

fn shorten(text: &str) -> String {
    if text.len() <= MAX_QUOTED {
        return text.to_owned();
    }
    let mut end = MAX_QUOTED;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &text[..end])
}
