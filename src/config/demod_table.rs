//! Serde adaptor between `Settings::demods` (a `Vec`) and the index-keyed table of the files
//! and the node tree (`[demods]` with `0 = { … }` … `31 = { … }`), so that `/demods/3/harmonic`
//! is key `harmonic` of `[demods.3]`. Exactly [`DEMODULATOR_COUNT`] entries, indices 0 … 31.

use std::fmt;

use serde::de::{self, MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserializer, Serializer};

use super::settings::{DEMODULATOR_COUNT, DemodSettings};

/// Writes the bank as a map from the decimal index (a string key) to each demodulator.
pub fn serialize<S: Serializer>(
    demods: &[DemodSettings],
    serializer: S,
) -> Result<S::Ok, S::Error> {
    let mut map = serializer.serialize_map(Some(demods.len()))?;
    for (index, demod) in demods.iter().enumerate() {
        map.serialize_entry(&index.to_string(), demod)?;
    }
    map.end()
}

/// Reads the index-keyed map; every index 0 … 31 must appear exactly once.
pub fn deserialize<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> Result<Vec<DemodSettings>, D::Error> {
    deserializer.deserialize_map(BankVisitor)
}

struct BankVisitor;

impl<'de> Visitor<'de> for BankVisitor {
    type Value = Vec<DemodSettings>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "a table of demodulators keyed by index 0 … {}",
            DEMODULATOR_COUNT - 1
        )
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut slots: Vec<Option<DemodSettings>> = vec![None; DEMODULATOR_COUNT];
        while let Some(key) = map.next_key::<String>()? {
            // Only the canonical spelling ("3", not "03") names a node of the tree.
            let index = key
                .parse::<usize>()
                .ok()
                .filter(|&i| i < DEMODULATOR_COUNT && i.to_string() == key)
                .ok_or_else(|| {
                    de::Error::custom(format!(
                        "unknown key /demods/{key}: demodulators are numbered 0 … {}",
                        DEMODULATOR_COUNT - 1
                    ))
                })?;
            if slots[index].is_some() {
                return Err(de::Error::custom(format!("/demods/{index} is given twice")));
            }
            slots[index] = Some(map.next_value()?);
        }
        let missing: Vec<String> = slots
            .iter()
            .enumerate()
            .filter(|(_, slot)| slot.is_none())
            .map(|(index, _)| index.to_string())
            .collect();
        if !missing.is_empty() {
            return Err(de::Error::custom(format!(
                "[demods] lacks demodulator(s) {}: all of 0 … {} must be given",
                missing.join(", "),
                DEMODULATOR_COUNT - 1
            )));
        }
        Ok(slots.into_iter().flatten().collect())
    }
}
