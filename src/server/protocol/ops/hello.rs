//! `hello`: who is there.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::fields::Fields;
use crate::server::protocol::{PROTOCOL_VERSION, ProtocolError};

/// Server name, versions and sample rate. No fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hello;

impl Hello {
    /// `hello` takes no fields; any given are ignored.
    pub fn parse(_: &Fields) -> Result<Self, ProtocolError> {
        Ok(Hello)
    }

    /// `server`, `version`, `protocol` and `sample_rate`.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        Ok(reply(json!({
            "server": "ftafm",
            "version": env!("CARGO_PKG_VERSION"),
            "protocol": PROTOCOL_VERSION,
            "sample_rate": ctx.sample_rate,
        })))
    }
}

impl<'de> Deserialize<'de> for Hello {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
