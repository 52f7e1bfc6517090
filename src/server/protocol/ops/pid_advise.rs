//! `pid_advise`: gains for a live PID unit (`/pids/N`) from a target bandwidth, as LabOne's
//! PID Advisor gives them: the loop's model ([`crate::control::LoopModel`]) built for the
//! unit's input and output at the settings in force, and [`crate::control::advise`] on it.
//! It does not apply them: the client sets them with `set`.
//!
//! The loops it models, and how, are [`crate::instrument::unit_loop`]'s (docs/loops.md, "The
//! PID advisor"); a unit it does not model is refused naming the unit's nodes.

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::config::{PID_COUNT, Settings};
use crate::control::{Advice, AdvisorError, Kind, advise};
use crate::instrument::unit_loop::{UnitLoop, unit_loop};
use crate::server::protocol::fields::{Fields, bad, describe, quote};
use crate::server::protocol::{ErrorCode, ProtocolError};

/// Gains for unit `unit` at a target bandwidth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PidAdvise {
    /// N of `/pids/N` (0 … [`PID_COUNT`] − 1).
    pub unit: usize,
    /// The closed loop's target −3 dB bandwidth (Hz, finite, > 0).
    pub bandwidth: f64,
    /// PI (D = 0) or PID.
    pub kind: Kind,
}

impl PidAdvise {
    /// `unit`, required: an integer 0 … 3; `bandwidth`, required: a number > 0 (Hz);
    /// `kind`, optional: `"pi"` (the default) or `"pid"`.
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        let last = PID_COUNT - 1;
        let unit = match fields.get("unit") {
            None | Some(Value::Null) => {
                return Err(bad(format!(
                    "op \"pid_advise\" needs field \"unit\", the PID unit N of /pids/N: an \
                     integer 0 … {last}"
                )));
            }
            Some(v) => v.as_u64().filter(|&n| n <= last as u64).ok_or_else(|| {
                bad(format!(
                    "field \"unit\" of op \"pid_advise\" must be an integer 0 … {last}, got {}",
                    describe(v)
                ))
            })? as usize,
        };
        let bandwidth = match fields.get("bandwidth") {
            None | Some(Value::Null) => {
                return Err(bad(
                    "op \"pid_advise\" needs field \"bandwidth\", the closed loop's target \
                     −3 dB bandwidth: a number > 0 (Hz)"
                        .to_owned(),
                ));
            }
            Some(v) => v
                .as_f64()
                .filter(|b| b.is_finite() && *b > 0.0)
                .ok_or_else(|| {
                    bad(format!(
                        "field \"bandwidth\" of op \"pid_advise\" must be a number > 0 (Hz), \
                         got {}",
                        describe(v)
                    ))
                })?,
        };
        let kind = match fields.get("kind") {
            None | Some(Value::Null) => Kind::Pi,
            Some(Value::String(k)) if k == "pi" => Kind::Pi,
            Some(Value::String(k)) if k == "pid" => Kind::Pid,
            Some(Value::String(k)) => {
                return Err(bad(format!(
                    "field \"kind\" of op \"pid_advise\" must be \"pi\" or \"pid\", got {}",
                    quote(k)
                )));
            }
            Some(v) => {
                return Err(bad(format!(
                    "field \"kind\" of op \"pid_advise\" must be \"pi\" or \"pid\", got {}",
                    describe(v)
                )));
            }
        };
        Ok(Self {
            unit,
            bandwidth,
            kind,
        })
    }

    /// `unit`, `kind`, `epoch` (of the settings modelled), `plant` (the model, in words),
    /// `p`, `i`, `d`, `d_bandwidth` (the gains in the unit's units, signed for its
    /// actuator), and the model's prediction of them: `bandwidth` (−3 dB, Hz), `crossover`
    /// (Hz), `phase_margin` (degrees), `overshoot` (a fraction of the step) and
    /// `settling_time` (2 %, s). A unit whose input and output the advisor does not model
    /// is `invalid_value`, naming its nodes and what is modelled; a bandwidth beyond the
    /// loop's reach is `invalid_value`, naming `bandwidth` and the reach. Nothing is set.
    pub(crate) async fn apply(
        self,
        ctx: &Context<'_>,
    ) -> Result<Map<String, Value>, ProtocolError> {
        let current = ctx.control.current();
        let UnitLoop { model, sign, plant } = model_of(&current.settings, self.unit)?;
        let (target, kind) = (self.bandwidth, self.kind);
        // A few milliseconds of searches and one step response: off the session's task.
        let advice = tokio::task::spawn_blocking(move || advise(&model, target, kind))
            .await
            .map_err(|e| {
                ProtocolError::new(ErrorCode::Internal, format!("the advisor failed: {e}"))
            })?
            .map_err(|e| refusal(self.unit, target, &e))?;
        Ok(reply(advice_fields(
            self.unit,
            kind,
            current.epoch,
            &plant,
            sign,
            &advice,
        )))
    }
}

/// The reply's fields for `advice`, its gains times `sign`.
fn advice_fields(
    unit: usize,
    kind: Kind,
    epoch: u64,
    plant: &str,
    sign: f64,
    advice: &Advice,
) -> Value {
    json!({
        "unit": unit,
        "kind": match kind { Kind::Pi => "pi", Kind::Pid => "pid" },
        "epoch": epoch,
        "plant": plant,
        // + 0.0: no −0 for an integrator alone.
        "p": sign * advice.gains.p + 0.0,
        "i": sign * advice.gains.i,
        // + 0.0: no −0 for a PI.
        "d": sign * advice.gains.d + 0.0,
        "d_bandwidth": advice.gains.d_bandwidth,
        "bandwidth": advice.bandwidth,
        "crossover": advice.crossover,
        "phase_margin": advice.phase_margin,
        "overshoot": advice.step.overshoot,
        "settling_time": advice.step.settling_time,
    })
}

/// The advisor's refusal, naming the field.
fn refusal(unit: usize, target: f64, e: &AdvisorError) -> ProtocolError {
    if let AdvisorError::Form(_) = e {
        return ProtocolError::new(
            ErrorCode::InvalidValue,
            format!("field \"kind\" of op \"pid_advise\" for /pids/{unit}: {e}"),
        );
    }
    let reach = match e {
        AdvisorError::Unreachable { best, .. } => {
            format!(": allowed 0 < bandwidth ≤ {best:.4} Hz for /pids/{unit}")
        }
        _ => String::new(),
    };
    ProtocolError::new(
        ErrorCode::InvalidValue,
        format!("field \"bandwidth\" of op \"pid_advise\" = {target} Hz{reach}: {e}"),
    )
}

/// The loop of `/pids/{unit}` at `settings` ([`unit_loop`]), its refusal `invalid_value`.
fn model_of(settings: &Settings, unit: usize) -> Result<UnitLoop, ProtocolError> {
    unit_loop(settings, unit).map_err(|e| ProtocolError::new(ErrorCode::InvalidValue, e))
}

impl<'de> Deserialize<'de> for PidAdvise {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}
