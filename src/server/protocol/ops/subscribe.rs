//! `subscribe`: start (or re-format) a stream for this client.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::fields::{Fields, bad, describe, quote, stream};
use crate::server::protocol::{Format, ProtocolError, StreamKind};

/// Start (or re-format) a stream for this client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Subscribe {
    /// Which stream.
    pub stream: StreamKind,
    /// JSON text frames (default) or binary frames.
    pub format: Format,
    /// Only every n-th message of the stream: those whose `seq` is a multiple of n (1, the
    /// default: all of them).
    pub every: u32,
    /// Output time points per message (1, the default: one message per point). More than
    /// one only for `demods` in binary frames: the batched layout.
    pub batch: u32,
}

impl Subscribe {
    /// `stream` (required, checked first), `format`, `every` and `batch` (optional; `null`
    /// counts as absent).
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        let (stream, format) = (stream(fields, "subscribe")?, format(fields)?);
        Ok(Subscribe {
            stream,
            format,
            every: every(fields)?,
            batch: batch(fields, stream, format)?,
        })
    }

    /// `stream`, `next_seq` (the seq of the first message the client can get), `every` and
    /// `batch`.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        let next_seq = ctx.subscriptions.subscribe(self);
        Ok(reply(json!({
            "stream": self.stream.name(),
            "next_seq": next_seq,
            "every": self.every,
            "batch": self.batch,
        })))
    }
}

impl<'de> Deserialize<'de> for Subscribe {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}

fn format(fields: &Fields) -> Result<Format, ProtocolError> {
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

fn every(fields: &Fields) -> Result<u32, ProtocolError> {
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

fn batch(fields: &Fields, stream: StreamKind, format: Format) -> Result<u32, ProtocolError> {
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
