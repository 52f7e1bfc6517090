//! `settings`: the running settings as a TOML config file.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::fields::Fields;
use crate::server::protocol::{ErrorCode, ProtocolError};

/// The running settings as a TOML config file (what `load_settings` and `--config` read).
/// No fields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings;

impl Settings {
    /// `settings` takes no fields; any given are ignored.
    pub fn parse(_: &Fields) -> Result<Self, ProtocolError> {
        Ok(Settings)
    }

    /// `toml` and the `epoch` of the settings it holds.
    pub(crate) fn apply(self, ctx: &Context<'_>) -> Result<Map<String, Value>, ProtocolError> {
        let current = ctx.control.current();
        let toml = crate::config::settings_toml(&current.settings)
            .map_err(|e| ProtocolError::new(ErrorCode::Internal, e))?;
        Ok(reply(json!({ "toml": toml, "epoch": current.epoch })))
    }
}

impl<'de> Deserialize<'de> for Settings {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
