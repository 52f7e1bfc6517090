//! Parsing one text frame into a [`Request`].

use serde_json::{Map, Value};

use super::{ErrorCode, Format, ProtocolError, StreamKind};

/// What a request asks for.
#[derive(Clone, Debug, PartialEq)]
pub enum Op {
    /// Server name, versions and sample rate.
    Hello,
    /// The nodes under `path` (all nodes when `None`).
    List {
        /// Path prefix, starting with `/`.
        path: Option<String>,
    },
    /// One node's value.
    Get {
        /// Node path, starting with `/`.
        path: String,
    },
    /// Change one node.
    Set {
        /// Node path, starting with `/`.
        path: String,
        /// The new value, unchecked (the node tree validates it).
        value: Value,
    },
    /// Change several nodes together, at one sample boundary (`set` with `values`).
    SetMany {
        /// (node path, new value) pairs, unchecked.
        values: Vec<(String, Value)>,
    },
    /// The running settings as a TOML config file.
    Settings,
    /// Lay a TOML config over the running settings, as one transactional change.
    LoadSettings {
        /// The TOML text (a whole file from `settings`, or a partial one).
        toml: String,
    },
    /// Start (or re-format) a stream for this client.
    Subscribe {
        /// Which stream.
        stream: StreamKind,
        /// JSON text frames (default) or binary frames.
        format: Format,
        /// Only every n-th message of the stream: those whose `seq` is a multiple of n
        /// (1, the default: all of them).
        every: u32,
        /// Output time points per message (1, the default: one message per point). More
        /// than one only for `demods` in binary frames: the batched layout.
        batch: u32,
    },
    /// The presets (real cantilevers and samples) the instrument can load.
    Presets,
    /// Load a preset: its nodes change together, as one transactional set.
    Preset {
        /// The preset's name (`ftafm presets`).
        name: String,
    },
    /// Stop a stream for this client.
    Unsubscribe {
        /// Which stream.
        stream: StreamKind,
    },
}

impl Op {
    /// Every op's name, as a request spells it.
    pub const NAMES: [&'static str; 10] = [
        "hello",
        "list",
        "get",
        "set",
        "settings",
        "load_settings",
        "presets",
        "preset",
        "subscribe",
        "unsubscribe",
    ];

    /// This op's name, as a request spells it.
    pub const fn name(&self) -> &'static str {
        match self {
            Op::Hello => "hello",
            Op::List { .. } => "list",
            Op::Get { .. } => "get",
            Op::Set { .. } | Op::SetMany { .. } => "set",
            Op::Settings => "settings",
            Op::LoadSettings { .. } => "load_settings",
            Op::Presets => "presets",
            Op::Preset { .. } => "preset",
            Op::Subscribe { .. } => "subscribe",
            Op::Unsubscribe { .. } => "unsubscribe",
        }
    }
}

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

/// Longest rendering of a client's value quoted back in an error message (bytes).
const MAX_QUOTED: usize = 60;

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
    match parse_op(&fields) {
        Ok(op @ Op::SetMany { .. }) => match repeated_values(text) {
            Some(error) => Err((id, error)),
            None => Ok(Request { id, op }),
        },
        Ok(op) => Ok(Request { id, op }),
        Err(error) => Err((id, error)),
    }
}

/// A batch `set` that gives a node twice: the object it was parsed into kept only the last
/// value, which the client cannot have meant (it might as well have meant the first), so
/// the request is refused, naming the paths. Reads `text` again, keys in order, since the
/// parsed object no longer knows. `None` when every key of `values` is given once.
fn repeated_values(text: &str) -> Option<ProtocolError> {
    let Err(e) = serde_json::from_str::<ValuesKeys>(text) else {
        return None;
    };
    // The text parsed as JSON before, so this can only be a repeated key.
    let message = e.to_string();
    let message = message.split(" at line ").next().unwrap_or(&message);
    Some(bad(format!("field \"values\" of op \"set\" {message}")))
}

/// The top level of a request, read only to check that no key of its `values` object
/// repeats (nor `values` itself).
struct ValuesKeys;

impl<'de> serde::Deserialize<'de> for ValuesKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(TopVisitor)
    }
}

struct TopVisitor;

impl<'de> serde::de::Visitor<'de> for TopVisitor {
    type Value = ValuesKeys;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a request object")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<ValuesKeys, A::Error> {
        let mut seen = false;
        while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
            if key != "values" {
                map.next_value::<serde::de::IgnoredAny>()?;
            } else if std::mem::replace(&mut seen, true) {
                return Err(serde::de::Error::custom("is given twice"));
            } else {
                map.next_value::<UniqueKeys>()?;
            }
        }
        Ok(ValuesKeys)
    }
}

/// An object whose keys are all different (their values are not kept); any other value is
/// let through, for the top level to judge.
struct UniqueKeys;

impl<'de> serde::Deserialize<'de> for UniqueKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueKeysVisitor)
    }
}

struct UniqueKeysVisitor;

impl<'de> serde::de::Visitor<'de> for UniqueKeysVisitor {
    type Value = UniqueKeys;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an object of node path → value")
    }

    // `values` given twice with a first that is no object: the top level says so.
    fn visit_unit<E>(self) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_bool<E>(self, _: bool) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_i64<E>(self, _: i64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_u64<E>(self, _: u64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_f64<E>(self, _: f64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_str<E>(self, _: &str) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<UniqueKeys, A::Error> {
        while seq.next_element::<serde::de::IgnoredAny>()?.is_some() {}
        Ok(UniqueKeys)
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<UniqueKeys, A::Error> {
        let mut seen = std::collections::BTreeMap::<String, usize>::new();
        // Keys as decoded, so "\/a" and "/a" are the same node.
        while let Some(key) = map.next_key::<String>()? {
            map.next_value::<serde::de::IgnoredAny>()?;
            *seen.entry(key).or_default() += 1;
        }
        let repeated: Vec<String> = seen
            .iter()
            .filter(|&(_, &n)| n > 1)
            .map(|(path, n)| format!("{} {n} times", quote(path)))
            .collect();
        if repeated.is_empty() {
            return Ok(UniqueKeys);
        }
        Err(serde::de::Error::custom(format!(
            "gives {}: give each node once (a JSON object keeps only one of its values)",
            repeated.join(" and ")
        )))
    }
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

fn parse_op(fields: &Map<String, Value>) -> Result<Op, ProtocolError> {
    let op = match fields.get("op") {
        None => {
            return Err(bad(format!(
                "request has no \"op\" field; ops: {}",
                op_list()
            )));
        }
        Some(Value::String(op)) => op.as_str(),
        Some(other) => {
            return Err(bad(format!(
                "field \"op\" must be a string, one of {}; got {}",
                op_list(),
                describe(other)
            )));
        }
    };
    match op {
        "hello" => Ok(Op::Hello),
        "list" => Ok(Op::List {
            path: optional_path(fields, op)?,
        }),
        "get" => Ok(Op::Get {
            path: required_path(fields, op)?,
        }),
        "set" if fields.get("values").is_some_and(|v| !v.is_null()) => set_many(fields),
        "settings" => Ok(Op::Settings),
        "load_settings" => match fields.get("toml") {
            Some(Value::String(toml)) => Ok(Op::LoadSettings { toml: toml.clone() }),
            other => Err(bad(format!(
                "op \"load_settings\" needs field \"toml\", a string holding a config file (as \
                 op \"settings\" returns it); got {}",
                other.map_or_else(|| "nothing".to_owned(), describe)
            ))),
        },
        "set" => {
            let path = required_path(fields, op)?;
            let value = fields.get("value").cloned().ok_or_else(|| {
                bad(format!(
                    "op \"set\" needs field \"value\", the new value of {path}"
                ))
            })?;
            Ok(Op::Set { path, value })
        }
        "presets" => Ok(Op::Presets),
        "preset" => match fields.get("name") {
            Some(Value::String(name)) => Ok(Op::Preset { name: name.clone() }),
            _ => Err(bad(
                "op \"preset\" needs field \"name\", a string: one of the presets the op \
                 \"presets\" lists (e.g. \"tap300\")"
                    .to_owned(),
            )),
        },
        "subscribe" => {
            let (stream, format) = (stream(fields, op)?, format(fields)?);
            Ok(Op::Subscribe {
                stream,
                format,
                every: every(fields)?,
                batch: batch(fields, stream, format)?,
            })
        }
        "unsubscribe" => Ok(Op::Unsubscribe {
            stream: stream(fields, op)?,
        }),
        unknown => Err(ProtocolError::new(
            ErrorCode::UnknownOp,
            format!("unknown op {}; ops: {}", quote(unknown), op_list()),
        )),
    }
}

/// Most nodes one batch `set` may change (there are about 300).
const MAX_BATCH: usize = 1024;

/// `set` with `values`: an object of node path → value, at least one, no `path` beside it.
fn set_many(fields: &Map<String, Value>) -> Result<Op, ProtocolError> {
    if fields.get("path").is_some_and(|p| !p.is_null()) {
        return Err(bad(
            "op \"set\" takes either \"path\" and \"value\" (one node) or \"values\" (several), \
             not both"
                .to_owned(),
        ));
    }
    let example = r#"{"/drive/frequency": 1e5, "/surface/distance": 2e-8}"#;
    let values = match fields.get("values") {
        Some(Value::Object(values)) if !values.is_empty() && values.len() <= MAX_BATCH => values,
        Some(Value::Object(values)) if values.is_empty() => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" is empty: give at least one node, e.g. {example}"
            )));
        }
        Some(Value::Object(values)) => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" has {} nodes: at most {MAX_BATCH}",
                values.len()
            )));
        }
        other => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" must be an object of node path → value, e.g. \
                 {example}; got {}",
                other.map_or_else(|| "nothing".to_owned(), describe)
            )));
        }
    };
    let mut pairs = Vec::with_capacity(values.len());
    for (path, value) in values {
        if !path.starts_with('/') {
            return Err(bad(format!(
                "key {} of field \"values\" of op \"set\" must be a node path starting with \
                 \"/\" (such as \"/drive/frequency\")",
                quote(path)
            )));
        }
        pairs.push((path.clone(), value.clone()));
    }
    Ok(Op::SetMany { values: pairs })
}

fn required_path(fields: &Map<String, Value>, op: &str) -> Result<String, ProtocolError> {
    match fields.get("path") {
        None | Some(Value::Null) => Err(bad(format!(
            "op \"{op}\" needs field \"path\", a node path starting with \"/\" such as \
             \"/drive/frequency\""
        ))),
        Some(value) => check_path(value, op),
    }
}

fn optional_path(fields: &Map<String, Value>, op: &str) -> Result<Option<String>, ProtocolError> {
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

fn stream(fields: &Map<String, Value>, op: &str) -> Result<StreamKind, ProtocolError> {
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

fn format(fields: &Map<String, Value>) -> Result<Format, ProtocolError> {
    let allowed = "must be \"json\" (the default) or \"binary\"";
    match fields.get("format") {
        None | Some(Value::Null) => Ok(Format::Json),
        Some(Value::String(name)) => Format::from_name(name)
            .ok_or_else(|| bad(format!("field \"format\" {allowed}, got {}", quote(name)))),
        Some(other) => Err(bad(format!(
            "field \"format\" {allowed}, got {}",
            describe(other)
        ))),
    }
}

/// Most messages a subscription may skip between two it delivers.
pub const MAX_EVERY: u32 = 1_000_000;

fn every(fields: &Map<String, Value>) -> Result<u32, ProtocolError> {
    let allowed = format!("must be an integer 1 … {MAX_EVERY} (1, the default: every message)");
    match fields.get("every") {
        None | Some(Value::Null) => Ok(1),
        Some(Value::Number(n)) => n
            .as_u64()
            .filter(|&n| (1..=u64::from(MAX_EVERY)).contains(&n))
            .map(|n| n as u32)
            .ok_or_else(|| bad(format!("field \"every\" {allowed}, got {n}"))),
        Some(other) => Err(bad(format!(
            "field \"every\" {allowed}, got {}",
            describe(other)
        ))),
    }
}

/// Most output time points one batched `demods` message holds.
pub const MAX_POINTS: u32 = 1000;

fn batch(
    fields: &Map<String, Value>,
    stream: StreamKind,
    format: Format,
) -> Result<u32, ProtocolError> {
    let allowed =
        format!("must be an integer 1 … {MAX_POINTS} (1, the default: one time point per message)");
    let n = match fields.get("batch") {
        None | Some(Value::Null) => return Ok(1),
        Some(Value::Number(n)) => n
            .as_u64()
            .filter(|&n| (1..=u64::from(MAX_POINTS)).contains(&n))
            .map(|n| n as u32)
            .ok_or_else(|| bad(format!("field \"batch\" {allowed}, got {n}")))?,
        Some(other) => {
            return Err(bad(format!(
                "field \"batch\" {allowed}, got {}",
                describe(other)
            )));
        }
    };
    if n > 1 && (stream != StreamKind::Demods || format != Format::Binary) {
        return Err(bad(format!(
            "field \"batch\" above 1 is for the stream \"demods\" in \"format\": \"binary\" \
             only (got stream {}, format {})",
            quote(stream.name()),
            quote(format.name())
        )));
    }
    Ok(n)
}

fn bad(message: String) -> ProtocolError {
    ProtocolError::new(ErrorCode::BadRequest, message)
}

fn op_list() -> String {
    Op::NAMES.join(", ")
}

/// `a number (3)`, `an array ([1,2])`, `null`…, shortened for long values.
fn describe(value: &Value) -> String {
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
fn quote(text: &str) -> String {
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
