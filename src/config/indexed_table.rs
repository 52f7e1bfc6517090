//! Serde adaptor between a `Vec` of a table's entries (demodulators, inclusions) and the index-keyed table
//! of the files and the node tree: `[demods]` with `0 = { … }` … `31 = { … }`, `[inclusions]`
//! with `0 = { … }` … `7 = { … }`, so that `/demods/3/harmonic` is key `harmonic` of
//! `[demods.3]`. Exactly [`Indexed::COUNT`] entries, indices 0 … COUNT − 1, each once.
//!
//! Used as `#[serde(with = "super::indexed_table")]` on a `Vec<T>` with `T: Indexed`.

use std::fmt;
use std::marker::PhantomData;

use serde::de::{self, MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// An entry of an index-keyed table of the tree (`/TABLE/N/…`).
pub trait Indexed {
    /// How many entries the table always has; the indices are 0 … `COUNT` − 1.
    const COUNT: usize;
    /// The table's key at the top level, e.g. `"demods"` for `[demods]` and `/demods/N`.
    const TABLE: &'static str;
    /// What one entry is called in messages, e.g. `"demodulator"`.
    const ITEM: &'static str;
}

/// Writes the entries as a map from the decimal index (a string key) to each entry.
pub fn serialize<T, S>(entries: &[T], serializer: S) -> Result<S::Ok, S::Error>
where
    T: Indexed + Serialize,
    S: Serializer,
{
    let mut map = serializer.serialize_map(Some(entries.len()))?;
    for (index, entry) in entries.iter().enumerate() {
        map.serialize_entry(&index.to_string(), entry)?;
    }
    map.end()
}

/// Reads the index-keyed map; every index 0 … `T::COUNT` − 1 must appear exactly once.
pub fn deserialize<'de, T, D>(deserializer: D) -> Result<Vec<T>, D::Error>
where
    T: Indexed + Deserialize<'de>,
    D: Deserializer<'de>,
{
    deserializer.deserialize_map(TableVisitor(PhantomData))
}

struct TableVisitor<T>(PhantomData<T>);

impl<'de, T: Indexed + Deserialize<'de>> Visitor<'de> for TableVisitor<T> {
    type Value = Vec<T>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(
            f,
            "a table of {}s keyed by index 0 … {}",
            T::ITEM,
            T::COUNT - 1
        )
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let (table, item, last) = (T::TABLE, T::ITEM, T::COUNT - 1);
        let mut slots: Vec<Option<T>> = (0..T::COUNT).map(|_| None).collect();
        while let Some(key) = map.next_key::<String>()? {
            // Only the canonical spelling ("3", not "03") names a node of the tree.
            let index = key
                .parse::<usize>()
                .ok()
                .filter(|&i| i < T::COUNT && i.to_string() == key)
                .ok_or_else(|| {
                    de::Error::custom(format!(
                        "unknown key /{table}/{key}: {item}s are numbered 0 … {last}"
                    ))
                })?;
            if slots[index].is_some() {
                return Err(de::Error::custom(format!(
                    "/{table}/{index} is given twice"
                )));
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
                "[{table}] lacks {item}(s) {}: all of 0 … {last} must be given",
                missing.join(", ")
            )));
        }
        Ok(slots.into_iter().flatten().collect())
    }
}

#[cfg(test)]
mod tests {
    use crate::config::{DEFAULT_TOML, Settings};

    /// The default file with its `[table]` section's entry `index` line rewritten.
    fn default_with(table: &str, from: &str, to: &str) -> String {
        let at = DEFAULT_TOML.find(&format!("[{table}]")).unwrap();
        let (head, tail) = DEFAULT_TOML.split_at(at);
        format!("{head}{}", tail.replacen(from, to, 1))
    }

    fn error(text: &str) -> String {
        toml::from_str::<Settings>(text).unwrap_err().to_string()
    }

    #[test]
    fn unknown_indices_name_the_table_and_its_range() {
        let text = default_with("demods", "\n31 = ", "\n40 = ");
        assert!(
            error(&text).contains("unknown key /demods/40: demodulators are numbered 0 … 31"),
            "{}",
            error(&text)
        );
        let text = default_with("inclusions", "\n7 = ", "\n07 = ");
        assert!(
            error(&text).contains("unknown key /inclusions/07: inclusions are numbered 0 … 7"),
            "{}",
            error(&text)
        );
    }

    #[test]
    fn missing_indices_are_listed() {
        let text = default_with("inclusions", "\n3 = ", "\n# 3 = ");
        assert!(
            error(&text).contains("[inclusions] lacks inclusion(s) 3: all of 0 … 7 must be given"),
            "{}",
            error(&text)
        );
        let text = default_with("demods", "\n0 = ", "\n# 0 = ");
        assert!(
            error(&text).contains("[demods] lacks demodulator(s) 0: all of 0 … 31 must be given"),
            "{}",
            error(&text)
        );
    }

    #[test]
    fn json_round_trips_through_the_index_keys() {
        let settings = crate::config::default_settings();
        let json = serde_json::to_value(&settings).unwrap();
        assert_eq!(json["inclusions"]["7"]["shape"], "disc");
        assert_eq!(json["demods"]["31"]["harmonic"], 32);
        let back: Settings = serde_json::from_value(json).unwrap();
        assert_eq!(back, settings);
    }
}
