//! Replays every vector of spec/vectors: each frame must give the recorded
//! outcome and the mirror must end in the recorded state. Also checks that
//! every error class of the spec has a vector.

mod common;

use std::collections::BTreeSet;
use std::path::PathBuf;

use psao_codec::{Decoder, Limits};

fn spec_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec")
}

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len() % 2 == 0, "odd hex length");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// Replays one vector file; returns the error classes it exercised.
fn replay(path: &PathBuf) -> BTreeSet<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    let mut limits = Limits::default();
    let mut decoder: Option<Decoder> = None;
    let mut last: Option<String> = None;
    let mut errors = BTreeSet::new();
    let mut lines = text.lines();
    let mut state = None;
    for line in lines.by_ref() {
        if line.starts_with('#') || line.is_empty() {
            continue;
        }
        let (word, rest) = line.split_once(' ').unwrap_or((line, ""));
        match word {
            "limit" => {
                let (n, v) = rest.split_once(' ').unwrap();
                assert!(limits.set(n, v.parse().unwrap()), "unknown limit {n}");
            }
            "frame" => {
                let d = decoder.get_or_insert_with(|| Decoder::new(limits));
                let result = d.receive(&unhex(rest));
                if let Err(e) = &result {
                    errors.insert(e.code().to_string());
                }
                last = Some(psao_tests::raw::outcome(&result));
            }
            "expect" => {
                assert_eq!(last.take().as_deref(), Some(rest), "{name}: outcome");
            }
            "state" => {
                state = Some(lines.by_ref().map(|l| format!("{l}\n")).collect::<String>());
                break;
            }
            other => panic!("{name}: unknown line `{other}`"),
        }
    }
    let d = decoder.unwrap_or_else(|| panic!("{name}: no frame"));
    assert_eq!(
        d.mirror().describe(),
        state.expect("state section"),
        "{name}: final state"
    );
    errors
}

#[test]
fn every_vector_replays() {
    let mut paths: Vec<_> = std::fs::read_dir(spec_dir().join("vectors"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "txt"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 20, "only {} vectors", paths.len());
    let mut covered = BTreeSet::new();
    for p in &paths {
        covered.extend(replay(p));
    }
    // Error classes listed in the spec's table (rows like "| `name` | layer | ...").
    let spec = std::fs::read_to_string(spec_dir().join("wire-format.md")).unwrap();
    let table = spec
        .split("Error classes")
        .nth(1)
        .expect("error class table");
    let classes: BTreeSet<String> = table
        .lines()
        .filter_map(|l| l.strip_prefix("| `"))
        .filter_map(|l| l.split('`').next())
        .map(str::to_string)
        .collect();
    assert!(classes.len() > 30, "parsed {} classes", classes.len());
    let untestable: BTreeSet<String> = ["compression_unavailable".to_string()].into();
    let missing: Vec<_> = classes
        .difference(&covered)
        .filter(|c| !untestable.contains(*c))
        .collect();
    assert!(
        missing.is_empty(),
        "error classes without a vector: {missing:?}"
    );
    let unknown: Vec<_> = covered.difference(&classes).collect();
    assert!(
        unknown.is_empty(),
        "errors the spec does not list: {unknown:?}"
    );
}
