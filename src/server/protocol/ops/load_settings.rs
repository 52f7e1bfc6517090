//! `load_settings`: lay a TOML config over the running settings, as one transactional
//! change through [`Control::change`](crate::instrument::Control::change).

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::instrument::ChangeError;
use crate::server::protocol::ProtocolError;
use crate::server::protocol::fields::{Fields, bad, describe};

/// Lay a TOML config over the running settings.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadSettings {
    /// The TOML text (a whole file from `settings`, or a partial one).
    pub toml: String,
}

impl LoadSettings {
    /// `toml`, required: a string.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        match fields.get("toml") {
            Some(Value::String(toml)) => Ok(LoadSettings { toml: toml.clone() }),
            other => Err(bad(format!(
                "op \"load_settings\" needs field \"toml\", a string holding a config file (as \
                 op \"settings\" returns it); got {}",
                other.map_or_else(|| "nothing".to_owned(), describe)
            ))),
        }
    }

    /// `t`, `epoch` and the new settings' `warnings`. A text that changes
    /// `/synth/sample_rate` is `read_only`: that takes a restart.
    pub(crate) async fn apply(
        self,
        ctx: &Context<'_>,
    ) -> Result<Map<String, Value>, ProtocolError> {
        let toml = self.toml;
        let c = ctx
            .control
            .change("settings".to_owned(), move |c| {
                let s = &c.settings;
                let next = crate::config::overlay_str((**s).clone(), &toml, "settings")?;
                if next.synth.sample_rate != s.synth.sample_rate {
                    return Err(ChangeError::ReadOnly(format!(
                        "/synth/sample_rate is read-only at runtime: these settings have {} \
                         Hz, the instrument runs at {} Hz; start the daemon with them \
                         (ftafm --config FILE) instead",
                        next.synth.sample_rate, s.synth.sample_rate
                    )));
                }
                Ok((next, None, ()))
            })
            .await?;
        Ok(reply(json!({
            "t": c.t,
            "epoch": c.epoch,
            "warnings": c.settings.warnings(),
        })))
    }
}

impl<'de> Deserialize<'de> for LoadSettings {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
