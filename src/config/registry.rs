//! The registry: the one list of nodes, built once, with lookup by path and the tables of
//! the tree (what keys `[sample]`, `[inclusions.2]` or `[demods.3]` have) for the config
//! loader and messages.

use std::collections::{BTreeMap, HashMap};
use std::sync::OnceLock;

use super::field::Field;
use super::show::cut;
use super::spec::NodeSpec;

struct Registry {
    specs: Vec<NodeSpec>,
    by_path: HashMap<String, usize>,
    /// Every table path ("" is the top level) and its keys, in tree order.
    tables: BTreeMap<String, Vec<String>>,
}

fn registry_data() -> &'static Registry {
    static REGISTRY: OnceLock<Registry> = OnceLock::new();
    REGISTRY.get_or_init(|| {
        let specs: Vec<NodeSpec> = Field::every().into_iter().map(NodeSpec::new).collect();
        let by_path = specs
            .iter()
            .enumerate()
            .map(|(i, spec)| (spec.path.clone(), i))
            .collect();
        let mut tables: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for spec in &specs {
            let mut table = String::new();
            for key in spec.path.split('/').skip(1) {
                let keys = tables.entry(table.clone()).or_default();
                if !keys.iter().any(|k| k == key) {
                    keys.push(key.to_owned());
                }
                table = format!("{table}/{key}");
            }
        }
        Registry {
            specs,
            by_path,
            tables,
        }
    })
}

/// Every node, in tree order: the scalar nodes, then `/inclusions/0/…` … `/inclusions/7/…`,
/// then `/demods/0/…` … `/demods/31/…`.
pub fn registry() -> &'static [NodeSpec] {
    &registry_data().specs
}

/// The node at `path`, if there is one.
pub fn node(path: &str) -> Option<&'static NodeSpec> {
    let registry = registry_data();
    registry.by_path.get(path).map(|&i| &registry.specs[i])
}

/// The keys of the table at `path` (`""` is the top level, `/sample`, `/demods/3`), or
/// `None` if `path` is no table of the tree.
pub fn table_keys(path: &str) -> Option<&'static [String]> {
    registry_data().tables.get(path).map(Vec::as_slice)
}

/// A table path as TOML writes its header: `/demods/3` → `[demods.3]`.
pub(crate) fn toml_table_name(path: &str) -> String {
    if path.is_empty() {
        "the top level".to_owned()
    } else {
        format!("[{}]", path.trim_start_matches('/').replace('/', "."))
    }
}

/// Keys for a message; a run of indices reads `0 … 31`.
pub(crate) fn key_list(keys: &[String]) -> String {
    let indices: Option<Vec<usize>> = keys.iter().map(|k| k.parse().ok()).collect();
    match indices {
        Some(run) if run.len() > 2 && run.windows(2).all(|w| w[1] == w[0] + 1) => {
            format!("{} … {}", run[0], run[run.len() - 1])
        }
        _ => keys.join(", "),
    }
}

/// Whether `path` is written as node paths are: `/`, then segments separated by single
/// slashes, none empty (no `//`, no trailing `/`). The same rule for `get`, `set` and
/// `list` (whose `/` alone means the whole tree).
pub(crate) fn well_formed(path: &str) -> bool {
    path.strip_prefix('/')
        .is_some_and(|rest| rest.split('/').all(|segment| !segment.is_empty()))
}

/// The message of [`NodeError::UnknownPath`]: says why a path is malformed, or what the
/// nearest existing table holds. The path is quoted cut short.
pub(crate) fn unknown_path_message(path: &str) -> String {
    if !well_formed(path) {
        return format!(
            "malformed path {:?}: a node path is \"/\" then names separated by single \"/\", \
             with no empty name and no trailing \"/\" (such as /drive/frequency or /demods/3)",
            cut(path)
        );
    }
    let shown = cut(path);
    if let Some(keys) = table_keys(path).filter(|_| !path.is_empty()) {
        return format!(
            "unknown node {shown}: that is a table; its keys: {}",
            key_list(keys)
        );
    }
    let mut table = path;
    loop {
        table = table.rsplit_once('/').map_or("", |(parent, _)| parent);
        if let Some(keys) = table_keys(table) {
            let name = if table.is_empty() {
                "the top level"
            } else {
                table
            };
            return format!("unknown node {shown}; keys of {name}: {}", key_list(keys));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::field::Field;
    use crate::config::settings::{DEMODULATOR_COUNT, INCLUSION_COUNT, PID_COUNT};

    #[test]
    fn registry_lists_each_path_once() {
        let scalars = Field::every()
            .iter()
            .filter(|f| {
                !["/inclusions/", "/demods/", "/pids/"]
                    .iter()
                    .any(|table| f.path().starts_with(table))
            })
            .count();
        assert_eq!(
            registry().len(),
            scalars
                + Field::inclusion(0).len() * INCLUSION_COUNT
                + Field::demod(0).len() * DEMODULATOR_COUNT
                + Field::pid(0).len() * PID_COUNT
        );
        assert_eq!(registry_data().by_path.len(), registry().len());
        assert_eq!(
            node("/inclusions/7/poisson").unwrap().field,
            Field::InclusionPoisson(7)
        );
        assert!(node("/inclusions/8/poisson").is_none());
        assert_eq!(node("/demods/31/rate").unwrap().field, Field::DemodRate(31));
        assert!(node("/demods/32/rate").is_none());
    }

    #[test]
    fn tables_mirror_the_paths() {
        let top = table_keys("").unwrap();
        assert_eq!(top[0], "cantilever");
        assert_eq!(top.last().unwrap(), "pids");
        assert_eq!(
            top[top.len() - 6..],
            [
                "scan",
                "feedback",
                "sweeper",
                "inclusions",
                "demods",
                "pids"
            ]
        );
        assert_eq!(key_list(table_keys("/pids").unwrap()), "0 … 3");
        assert_eq!(key_list(table_keys("/inclusions").unwrap()), "0 … 7");
        assert_eq!(
            table_keys("/inclusions/2").unwrap(),
            [
                "enable",
                "shape",
                "x",
                "y",
                "width",
                "length",
                "height",
                "youngs_modulus",
                "relative_modulus",
                "poisson"
            ]
        );
        assert_eq!(
            table_keys("/sample").unwrap(),
            ["youngs_modulus", "poisson"]
        );
        assert_eq!(key_list(table_keys("/demods").unwrap()), "0 … 31");
        assert!(table_keys("/sample/poisson").is_none());
    }

    #[test]
    fn unknown_paths_point_at_their_table() {
        let message = unknown_path_message("/sample/youngs_moduls");
        assert!(message.contains("youngs_modulus, poisson"), "{message}");
        let message = unknown_path_message("/nothing/here");
        assert!(message.contains("the top level"), "{message}");
        let message = unknown_path_message("/sample");
        assert!(message.contains("table"), "{message}");
        for malformed in ["//", "/sample/", "/sample//poisson", "sample/poisson", ""] {
            let message = unknown_path_message(malformed);
            assert!(
                message.starts_with("malformed path"),
                "{malformed}: {message}"
            );
        }
        let long = format!("/{}", "x".repeat(20_000_000));
        let message = unknown_path_message(&long);
        // The cut path and the top level's keys: a few hundred bytes, not 20 MB.
        assert!(message.len() < 320, "{} bytes", message.len());
        assert!(message.contains("(20000001 bytes)"), "{message}");
    }
}
