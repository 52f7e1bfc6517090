//! The protocol's ops, one file each (as tokio's mini-redis has its commands): the op's
//! request as a struct, its `parse` (of the op's [`Fields`] as a client sent them, which is
//! also its `Deserialize`) and its `apply`, which carries it out against a [`Context`] and
//! makes the reply's fields.
//!
//! [`Op`] is the request, tagged by its `op` field: serde picks the op by its name, the op's
//! own parse reads the rest, with error messages that name the field, the op, what was
//! given and what is allowed (and the error code: `unknown_stream` for a stream no one
//! knows, `bad_request` otherwise). [`super::parse_request`] reads a text frame into one.
//!
//! An op sees only its [`Context`]: the control plane (the settings and their one writer,
//! [`Control::change`]), the newest measured values, and the requesting client's
//! subscriptions. The socket, the queues and the subscriptions' bookkeeping stay with the
//! session that calls it.

mod get;
mod hello;
mod list;
mod load_settings;
mod pid_advise;
mod preset;
mod presets;
mod set;
mod settings;
mod subscribe;
mod unsubscribe;

use std::sync::{Arc, Mutex};

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value};

use super::fields::Fields;
use super::{ErrorCode, ProtocolError, StreamKind};
use crate::instrument::Control;
use crate::pipeline::DemodFrame;

pub use get::{Get, MAX_PATHS};
pub use hello::Hello;
pub use list::List;
pub use load_settings::LoadSettings;
pub use pid_advise::PidAdvise;
pub use preset::Preset;
pub use presets::Presets;
pub(super) use set::repeated_values;
pub use set::{MAX_BATCH, Set};
pub use settings::Settings;
pub use subscribe::{MAX_EVERY, MAX_POINTS, Subscribe};
pub use unsubscribe::Unsubscribe;

/// What a request asks for: one op, tagged by the request's `op` field.
///
/// Deserialize it from a request object whose `op` is one of [`Op::NAMES`] (as
/// [`super::parse_request`] does, which words the errors of the envelope: not JSON, no `op`,
/// an unknown op); an op's refusal of its fields comes out of serde as its message, a line
/// break and its code.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Op {
    /// Server name, versions and sample rate.
    Hello(Hello),
    /// The nodes under a path.
    List(List),
    /// One node's value, or a measured value.
    Get(Get),
    /// Change one node, or several together.
    Set(Set),
    /// The running settings as a TOML config file.
    Settings(Settings),
    /// Lay a TOML config over the running settings.
    LoadSettings(LoadSettings),
    /// The presets the instrument can load.
    Presets(Presets),
    /// Load a preset.
    Preset(Preset),
    /// Start (or re-format) a stream for this client.
    Subscribe(Subscribe),
    /// Stop a stream for this client.
    Unsubscribe(Unsubscribe),
    /// Gains for a PID unit from a target bandwidth (not applied).
    PidAdvise(PidAdvise),
}

impl Op {
    /// Every op's name, as a request spells it.
    pub const NAMES: [&'static str; 11] = [
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
        "pid_advise",
    ];

    /// This op's name, as a request spells it.
    pub const fn name(&self) -> &'static str {
        match self {
            Op::Hello(_) => "hello",
            Op::List(_) => "list",
            Op::Get(_) => "get",
            Op::Set(_) => "set",
            Op::Settings(_) => "settings",
            Op::LoadSettings(_) => "load_settings",
            Op::Presets(_) => "presets",
            Op::Preset(_) => "preset",
            Op::Subscribe(_) => "subscribe",
            Op::Unsubscribe(_) => "unsubscribe",
            Op::PidAdvise(_) => "pid_advise",
        }
    }

    /// Carries the op out; the reply's fields (the envelope, `id` and `ok`, is the caller's).
    pub(crate) async fn apply(
        self,
        ctx: &Context<'_>,
    ) -> Result<Map<String, Value>, ProtocolError> {
        match self {
            Op::Hello(op) => op.apply(ctx),
            Op::List(op) => op.apply(ctx),
            Op::Get(op) => op.apply(ctx),
            Op::Set(op) => op.apply(ctx).await,
            Op::Settings(op) => op.apply(ctx),
            Op::LoadSettings(op) => op.apply(ctx).await,
            Op::Presets(op) => op.apply(ctx),
            Op::Preset(op) => op.apply(ctx).await,
            Op::Subscribe(op) => op.apply(ctx),
            Op::Unsubscribe(op) => op.apply(ctx),
            Op::PidAdvise(op) => op.apply(ctx).await,
        }
    }
}

/// What the ops need of the daemon, and nothing more.
pub(crate) struct Context<'a> {
    /// The settings in force, their epoch, and their one writer ([`Control::change`]).
    pub control: &'a Arc<Control>,
    /// The photodiode sample rate (Hz), fixed while the daemon runs.
    pub sample_rate: f64,
    /// The lock-in's newest output, for `get` of `/demods/N/sample`.
    pub latest_demods: &'a Mutex<Option<DemodFrame>>,
    /// The requesting client's subscriptions.
    pub subscriptions: &'a (dyn Subscriptions + Sync),
}

/// A client's subscriptions, as `subscribe` and `unsubscribe` change them; the bookkeeping
/// behind them (batches in progress, what the force worker fits, where a stream's messages
/// start) is the session's.
pub(crate) trait Subscriptions {
    /// Starts (or re-formats) a stream for the client; the `seq` of the first message of it
    /// the client can get.
    fn subscribe(&self, subscription: Subscribe) -> u64;

    /// Stops a stream for the client.
    fn unsubscribe(&self, stream: StreamKind);
}

/// The reply's fields from a JSON object (anything else: none).
fn reply(value: Value) -> Map<String, Value> {
    match value {
        Value::Object(fields) => fields,
        _ => Map::new(),
    }
}

/// An op's `Deserialize`: its fields, read by its `parse`. A refusal travels through serde
/// as text, the message, a line break and the code (ending in the code, so that serde_json
/// never takes the end of a message for a position of its own); [`from_serde`] reads it back.
fn parse_with<'de, D, T>(
    deserializer: D,
    parse: impl FnOnce(&Fields) -> Result<T, ProtocolError>,
) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
{
    let fields = Fields::deserialize(deserializer)?;
    parse(&fields).map_err(|e| serde::de::Error::custom(format_args!("{}\n{}", e.message, e.code)))
}

/// An op's refusal as serde carried it ([`parse_with`]), back as the error it was; serde's
/// own errors are `bad_request`s.
pub(super) fn from_serde(error: &serde_json::Error) -> ProtocolError {
    let text = error.to_string();
    match text.rsplit_once('\n') {
        Some((message, code)) => match ErrorCode::from_name(code) {
            Some(code) => ProtocolError::new(code, message),
            None => ProtocolError::new(ErrorCode::BadRequest, text),
        },
        None => ProtocolError::new(ErrorCode::BadRequest, text),
    }
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;
    use serde_json::{Value, json};

    use super::{ErrorCode, Op, ProtocolError, from_serde, parse_with};

    /// Refuses with the message and code it is given.
    struct Refused;

    impl<'de> Deserialize<'de> for Refused {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            parse_with(d, |fields| {
                let text = |key: &str| fields[key].as_str().unwrap_or_default().to_owned();
                let code = ErrorCode::from_name(&text("code")).unwrap_or(ErrorCode::Internal);
                Err(ProtocolError::new(code, text("message")))
            })
        }
    }

    #[test]
    fn an_ops_refusal_comes_through_serde_as_it_was() {
        for code in ErrorCode::ALL {
            // Even a message that ends like serde_json's own positions.
            for message in [
                "field \"x\": 1: no",
                "needs \"value\", the new value of /a\nb at line 01 column 2",
                "/a at line 0 column 5",
            ] {
                let request = json!({"code": code.as_str(), "message": message});
                let Err(e) = serde_json::from_value::<Refused>(request) else {
                    panic!("refused");
                };
                assert_eq!(from_serde(&e), ProtocolError::new(code, message));
            }
        }
        let serdes = serde_json::from_value::<Op>(json!({"id": 1})).unwrap_err();
        assert_eq!(from_serde(&serdes).code, ErrorCode::BadRequest);
        let serdes = serde_json::from_value::<Op>(Value::Null).unwrap_err();
        assert_eq!(from_serde(&serdes).code, ErrorCode::BadRequest);
    }
}
