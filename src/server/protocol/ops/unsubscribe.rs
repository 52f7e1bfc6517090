//! `unsubscribe`: stop a stream for this client.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::fields::{Fields, stream};
use crate::server::protocol::{ProtocolError, StreamKind};

/// Stop a stream for this client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unsubscribe {
    /// Which stream.
    pub stream: StreamKind,
}

impl Unsubscribe {
    /// `stream`, required: a stream's name (else `unknown_stream`).
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        Ok(Unsubscribe {
            stream: stream(fields, "unsubscribe")?,
        })
    }

    /// `stream`.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        ctx.subscriptions.unsubscribe(self.stream);
        Ok(reply(json!({ "stream": self.stream.name() })))
    }
}

impl<'de> Deserialize<'de> for Unsubscribe {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
