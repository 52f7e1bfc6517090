//! The layering of `src/` (the README's layout table): each layer uses only those below it, and the
//! two real-time stages, `synth` and `dsp`, meet only through the ring; what both need (the
//! phase words, the pre-decimation grid) lives in `timebase`, below them.

use std::fs;
use std::path::Path;

/// Every `crate::<module>` that the Rust files under `dir` name.
fn crate_paths(dir: &Path) -> Vec<(String, String)> {
    let mut found = Vec::new();
    for entry in fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            found.extend(crate_paths(&path));
        } else if path.extension().is_some_and(|e| e == "rs") {
            let text = fs::read_to_string(&path).unwrap();
            for (i, _) in text.match_indices("crate::") {
                let module: String = text[i + 7..]
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                found.push((path.display().to_string(), module));
            }
        }
    }
    found
}

fn assert_uses_only(layer: &str, allowed: &[&str]) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src")
        .join(layer);
    let offending: Vec<_> = crate_paths(&dir)
        .into_iter()
        .filter(|(_, m)| m != layer && !allowed.contains(&m.as_str()))
        .collect();
    assert!(
        offending.is_empty(),
        "src/{layer} may use only {allowed:?}, but: {offending:?}"
    );
}

#[test]
fn the_synthesiser_and_the_dsp_meet_only_through_the_ring() {
    assert_uses_only(
        "synth",
        &["physics", "config", "model", "control", "timebase", "cpu"],
    );
    assert_uses_only("dsp", &["timebase", "cpu"]);
}

#[test]
fn the_physics_depends_on_nothing_above_it() {
    assert_uses_only("physics", &[]);
    assert_uses_only("control", &[]);
}

#[test]
fn the_schema_uses_no_physics_and_the_control_plane_no_transport() {
    // Whether settings can run is the model's question, never the schema's.
    assert_uses_only("config", &[]);
    assert_uses_only(
        "instrument",
        &[
            "config",
            "model",
            "physics",
            "inversion",
            "imaging",
            "sweep",
            "pipeline",
            "synth",
            "timebase",
            "cpu",
            // The loop models and the advisor (`unit_loop`): a leaf that uses nothing.
            "control",
        ],
    );
}

/// The modules of `src/<folder>` that each of its modules uses (`super::x`,
/// `crate::<folder>::x`), tests and comment lines (`//`, `//!`, `///`) left out: a doc link
/// is no dependency.
fn module_graph(folder: &str) -> std::collections::BTreeMap<String, Vec<String>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src")
        .join(folder);
    let mut graph = std::collections::BTreeMap::new();
    for entry in fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        if name == "mod" {
            continue;
        }
        let files: Vec<_> = if path.is_dir() {
            fs::read_dir(&path)
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|e| e == "rs"))
                .collect()
        } else {
            vec![path.clone()]
        };
        let mut uses = Vec::new();
        for file in files {
            let text = fs::read_to_string(file).unwrap();
            let text: String = text
                .split("#[cfg(test)]")
                .next()
                .unwrap_or("")
                .lines()
                .filter(|line| !line.trim_start().starts_with("//"))
                .flat_map(|line| [line, "\n"])
                .collect();
            let prefix = format!("crate::{folder}::");
            for marker in ["super::", prefix.as_str()] {
                for (i, _) in text.match_indices(marker) {
                    let used: String = text[i + marker.len()..]
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if used != name && !uses.contains(&used) {
                        uses.push(used);
                    }
                }
            }
        }
        graph.insert(name, uses);
    }
    graph
}

/// A module of `folder` that reaches itself through the others (depth first from each
/// module, each other module visited once).
fn import_circle(folder: &str) -> Option<String> {
    let graph = module_graph(folder);
    graph.keys().find_map(|start| {
        let mut seen = std::collections::BTreeSet::new();
        let mut stack: Vec<&String> = graph[start].iter().collect();
        while let Some(m) = stack.pop() {
            if m == start {
                return Some(start.clone());
            }
            if seen.insert(m.clone()) {
                stack.extend(graph.get(m).into_iter().flatten());
            }
        }
        None
    })
}

#[test]
fn no_import_circle_in_any_layer_with_modules() {
    for folder in ["config", "server", "instrument", "pipeline", "synth"] {
        assert_eq!(import_circle(folder), None, "src/{folder}");
    }
}
