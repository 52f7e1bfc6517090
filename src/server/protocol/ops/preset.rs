//! `preset`: load a preset; its nodes change together, as one transactional change through
//! [`Control::change`](crate::instrument::Control::change).

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::fields::{Fields, bad};
use crate::server::protocol::{ErrorCode, ProtocolError};

/// Load a preset.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Preset {
    /// The preset's name (`ftafm presets`).
    pub name: String,
}

impl Preset {
    /// `name`, required: a string.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        match fields.get("name") {
            Some(Value::String(name)) => Ok(Preset { name: name.clone() }),
            _ => Err(bad(
                "op \"preset\" needs field \"name\", a string: one of the presets the op \
                 \"presets\" lists (e.g. \"tap300\")"
                    .to_owned(),
            )),
        }
    }

    /// `preset`, `kind`, `t`, `epoch` and the new settings' `warnings`; a name no preset
    /// has is `invalid_value`. The running sample rate is kept (it is fixed while running):
    /// where a lever's harmonics need a higher one, the warnings say which.
    pub(crate) async fn apply(
        self,
        ctx: &Context<'_>,
    ) -> Result<Map<String, Value>, ProtocolError> {
        let preset = crate::config::preset(&self.name)
            .map_err(|e| ProtocolError::new(ErrorCode::InvalidValue, e.to_string()))?;
        let origin = format!("preset {}", preset.name);
        let c = ctx
            .control
            .change(origin.clone(), move |c| {
                let base = (*c.settings).clone();
                let running = base.synth.sample_rate;
                let mut next = crate::config::overlay_str(base, preset.toml, &origin)?;
                // The sample rate is fixed while running: a lever preset's stays for the
                // next start, and the reply's and status's warnings name it if the
                // harmonics need it.
                next.synth.sample_rate = running;
                next.validate()
                    .map_err(|error| crate::config::ConfigError::Invalid {
                        origin: origin.clone(),
                        error,
                    })?;
                Ok((next, None, ()))
            })
            .await?;
        Ok(reply(json!({
            "preset": preset.name,
            "kind": preset.kind,
            "t": c.t,
            "epoch": c.epoch,
            "warnings": c.settings.warnings(),
        })))
    }
}

impl<'de> Deserialize<'de> for Preset {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
