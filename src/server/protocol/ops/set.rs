//! `set`: change one node (`path`, `value`) or several together (`values`) while the
//! instrument runs, through the control plane's one write path ([`Control::change`]): all
//! or nothing, at one sample boundary.
//!
//! [`Control::change`]: crate::instrument::Control::change

use serde::{Deserialize, Deserializer};
use serde_json::{Map, Value, json};

use super::{Context, parse_with, reply};
use crate::server::protocol::ProtocolError;
use crate::server::protocol::fields::{Fields, bad, describe, quote, required_path};

/// Change one node, or several together.
#[derive(Clone, Debug, PartialEq)]
pub enum Set {
    /// One node (`path` and `value`).
    One {
        /// Node path, starting with `/`.
        path: String,
        /// The new value, unchecked (the node tree validates it).
        value: Value,
    },
    /// Several nodes together, at one sample boundary (`values`).
    Many {
        /// (node path, new value) pairs, unchecked.
        values: Vec<(String, Value)>,
    },
}

/// Most nodes one batch `set` may change (there are about 300).
pub const MAX_BATCH: usize = 1024;

impl Set {
    /// `values` (an object of node path → value, at least one, no `path` beside it) when it
    /// is given and not `null`; else `path` and `value`. A batch whose text gives a node
    /// twice is refused too, but that only the text knows ([`repeated_values`]).
    pub fn parse(fields: &Fields) -> Result<Self, ProtocolError> {
        if fields.get("values").is_some_and(|v| !v.is_null()) {
            return many(fields);
        }
        let path = required_path(fields, "set")?;
        let value = fields.get("value").cloned().ok_or_else(|| {
            bad(format!(
                "op \"set\" needs field \"value\", the new value of {path}"
            ))
        })?;
        Ok(Set::One { path, value })
    }

    /// The values as applied, `t` (when the change took effect, in simulated s) and the
    /// change's `epoch`: `path` and `value`, or `values`.
    pub(crate) async fn apply(
        self,
        ctx: &Context<'_>,
    ) -> Result<Map<String, Value>, ProtocolError> {
        match self {
            Set::One { path, value } => {
                let what = format!("{path} = {value}");
                let c = ctx
                    .control
                    .change(what, move |c| {
                        let mut next = (*c.settings).clone();
                        let applied = next.set(&path, &value)?;
                        Ok((next, Some(vec![path.clone()]), (path, applied)))
                    })
                    .await?;
                let (path, applied) = c.value;
                Ok(reply(
                    json!({ "path": path, "value": applied, "t": c.t, "epoch": c.epoch }),
                ))
            }
            Set::Many { values } => {
                let what = values
                    .iter()
                    .map(|(p, _)| p.as_str())
                    .collect::<Vec<_>>()
                    .join(", ");
                let c = ctx
                    .control
                    .change(what, move |c| {
                        let mut next = (*c.settings).clone();
                        let applied = next.set_many(&values)?;
                        let paths: Vec<String> = values.iter().map(|(p, _)| p.clone()).collect();
                        let applied: Map<String, Value> =
                            paths.iter().cloned().zip(applied).collect();
                        Ok((next, Some(paths), applied))
                    })
                    .await?;
                Ok(reply(
                    json!({ "values": c.value, "t": c.t, "epoch": c.epoch }),
                ))
            }
        }
    }
}

impl<'de> Deserialize<'de> for Set {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        parse_with(d, Self::parse)
    }
}

/// `set` with `values`: an object of node path → value, at least one, no `path` beside it.
fn many(fields: &Fields) -> Result<Set, ProtocolError> {
    if fields.get("path").is_some_and(|p| !p.is_null()) {
        return Err(bad(
            "op \"set\" takes either \"path\" and \"value\" (one node) or \"values\" (several), \
             not both"
                .to_owned(),
        ));
    }
    let example = r#"{"/drive/frequency": 1e5, "/surface/distance": 2e-8}"#;
    let values = match fields.get("values") {
        Some(Value::Object(values)) if !values.is_empty() && values.len() <= MAX_BATCH => values,
        Some(Value::Object(values)) if values.is_empty() => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" is empty: give at least one node, e.g. {example}"
            )));
        }
        Some(Value::Object(values)) => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" has {} nodes: at most {MAX_BATCH}",
                values.len()
            )));
        }
        other => {
            return Err(bad(format!(
                "field \"values\" of op \"set\" must be an object of node path → value, e.g. \
                 {example}; got {}",
                other.map_or_else(|| "nothing".to_owned(), describe)
            )));
        }
    };
    let mut pairs = Vec::with_capacity(values.len());
    for (path, value) in values {
        if !path.starts_with('/') {
            return Err(bad(format!(
                "key {} of field \"values\" of op \"set\" must be a node path starting with \
                 \"/\" (such as \"/drive/frequency\")",
                quote(path)
            )));
        }
        pairs.push((path.clone(), value.clone()));
    }
    Ok(Set::Many { values: pairs })
}

/// A batch `set` that gives a node twice: the object it was parsed into kept only the last
/// value, which the client cannot have meant (it might as well have meant the first), so
/// the request is refused, naming the paths. Reads `text` again, keys in order, since the
/// parsed object no longer knows. `None` when every key of `values` is given once.
pub(crate) fn repeated_values(text: &str) -> Option<ProtocolError> {
    let Err(e) = serde_json::from_str::<ValuesKeys>(text) else {
        return None;
    };
    // The text parsed as JSON before, so this can only be a repeated key.
    let message = e.to_string();
    let message = message.split(" at line ").next().unwrap_or(&message);
    Some(bad(format!("field \"values\" of op \"set\" {message}")))
}

/// The top level of a request, read only to check that no key of its `values` object
/// repeats (nor `values` itself).
struct ValuesKeys;

impl<'de> serde::Deserialize<'de> for ValuesKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(TopVisitor)
    }
}

struct TopVisitor;

impl<'de> serde::de::Visitor<'de> for TopVisitor {
    type Value = ValuesKeys;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a request object")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<ValuesKeys, A::Error> {
        let mut seen = false;
        while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
            if key != "values" {
                map.next_value::<serde::de::IgnoredAny>()?;
            } else if std::mem::replace(&mut seen, true) {
                return Err(serde::de::Error::custom("is given twice"));
            } else {
                map.next_value::<UniqueKeys>()?;
            }
        }
        Ok(ValuesKeys)
    }
}

/// An object whose keys are all different (their values are not kept); any other value is
/// let through, for the top level to judge.
struct UniqueKeys;

impl<'de> serde::Deserialize<'de> for UniqueKeys {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueKeysVisitor)
    }
}

struct UniqueKeysVisitor;

impl<'de> serde::de::Visitor<'de> for UniqueKeysVisitor {
    type Value = UniqueKeys;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("an object of node path → value")
    }

    // `values` given twice with a first that is no object: the top level says so.
    fn visit_unit<E>(self) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_bool<E>(self, _: bool) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_i64<E>(self, _: i64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_u64<E>(self, _: u64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_f64<E>(self, _: f64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_str<E>(self, _: &str) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<UniqueKeys, A::Error> {
        while seq.next_element::<serde::de::IgnoredAny>()?.is_some() {}
        Ok(UniqueKeys)
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<UniqueKeys, A::Error> {
        let mut seen = std::collections::BTreeMap::<String, usize>::new();
        // Keys as decoded, so "\/a" and "/a" are the same node.
        while let Some(key) = map.next_key::<String>()? {
            map.next_value::<serde::de::IgnoredAny>()?;
            *seen.entry(key).or_default() += 1;
        }
        let repeated: Vec<String> = seen
            .iter()
            .filter(|&(_, &n)| n > 1)
            .map(|(path, n)| format!("{} {n} times", quote(path)))
            .collect();
        if repeated.is_empty() {
            return Ok(UniqueKeys);
        }
        Err(serde::de::Error::custom(format!(
            "gives {}: give each node once (a JSON object keeps only one of its values)",
            repeated.join(" and ")
        )))
    }
}
