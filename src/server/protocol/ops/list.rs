//! `list`: the nodes of the settings tree, with their values and what `set` would accept.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::ProtocolError;
use crate::server::protocol::fields::{Fields, optional_path};

/// The nodes under `path` (all nodes when `None`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct List {
    /// Path prefix, starting with `/`.
    pub path: Option<String>,
}

impl List {
    /// `path`, optional (`null` counts as absent), starting with `/`.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        Ok(List {
            path: optional_path(fields, "list")?,
        })
    }

    /// `nodes`; a prefix that matches no node is `unknown_path`.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        let settings = ctx.control.settings();
        let nodes = match &self.path {
            Some(p) => settings.list(p).map_err(|e| ProtocolError::from(&e))?,
            None => settings.nodes(),
        };
        Ok(reply(json!({ "nodes": nodes })))
    }
}

impl<'de> Deserialize<'de> for List {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
