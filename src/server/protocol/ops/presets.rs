//! `presets`: the presets (real cantilevers and samples) the instrument can load.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::ProtocolError;
use crate::server::protocol::fields::Fields;

/// The presets the instrument can load, each with its name, kind and a summary. No fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Presets;

impl Presets {
    /// `presets` takes no fields; any given are ignored.
    pub fn parse(_: &Fields) -> Result<Self, ProtocolError> {
        Ok(Presets)
    }

    /// `presets`: `[{name, kind, summary}]`.
    pub(crate) fn apply(self, _: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        let presets: Vec<Value> = crate::config::PRESETS
            .iter()
            .map(|p| json!({ "name": p.name, "kind": p.kind, "summary": p.summary() }))
            .collect();
        Ok(reply(json!({ "presets": presets })))
    }
}

impl<'de> Deserialize<'de> for Presets {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
