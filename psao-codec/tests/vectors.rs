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
    assert!(s.len().is_multiple_of(2), "odd hex length");
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
    let mut digest = None;
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
            "digest" => {
                let d = decoder.get_or_insert_with(|| Decoder::new(limits));
                let got = d.mirror().digest().map(|d| format!("{d:08x}"));
                assert_eq!(got.as_deref().unwrap_or("none"), rest, "{name}: digest");
                digest = Some(rest.to_string());
            }
            "state" => {
                state = Some(lines.by_ref().map(|l| format!("{l}\n")).collect::<String>());
                break;
            }
            other => panic!("{name}: unknown line `{other}`"),
        }
    }
    let d = decoder.unwrap_or_else(|| panic!("{name}: no frame"));
    let state = state.expect("state section");
    assert_eq!(d.mirror().describe(), state, "{name}: final state");
    // The digest again, from the state text alone, by spec/wire-format.md
    // 7.5 (not with the codec's code).
    let independent = digest_of_state(&state).map(|d| format!("{d:08x}"));
    assert_eq!(
        independent.as_deref().unwrap_or("none"),
        digest.expect("digest line"),
        "{name}: digest recomputed from the state"
    );
    errors
}

/// spec/wire-format.md 7.5 from a vector's state listing: rebuilds each
/// instance's definition bytes and full arrays (empty entries
/// `(0xFFFFFFFF, 0xFFFFFFFF)`, words 0 where none is listed) and hashes
/// them in the spec's order.
fn digest_of_state(state: &str) -> Option<u32> {
    struct Inst {
        def: Vec<u8>,
        transform: Option<Vec<u8>>,
        entries: Vec<(u32, u32)>,
        cap: usize,
        words: Vec<u32>,
        cell_capacity: usize,
    }
    let mut lines = state.lines();
    let sequence: u32 = lines.next()?.strip_prefix("sequence ")?.parse().ok()?;
    let mut insts: Vec<(u32, Inst)> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        let field = |name: &str, k: usize| -> &str {
            let i = w.iter().position(|x| *x == name).unwrap();
            w[i + 1 + k]
        };
        let f = |name: &str, k: usize| field(name, k).parse::<f32>().unwrap().to_le_bytes();
        let u = |name: &str, k: usize| field(name, k).parse::<u32>().unwrap();
        let id: u32 = w[1].parse().unwrap();
        match w[0] {
            "instance" => {
                let mut def = Vec::new();
                for name in ["origin", "cell_size"] {
                    (0..3).for_each(|k| def.extend(f(name, k)));
                }
                (0..3).for_each(|k| def.extend(u("dims", k).to_le_bytes()));
                let overflow = if w.contains(&"overflow") { 0x80 } else { 0 };
                def.extend([
                    u("table_log2", 0) as u8,
                    u("bucket_capacity", 0) as u8,
                    u("cell_capacity", 0) as u8,
                    u("point_format", 0) as u8 | overflow,
                ]);
                def.extend(u("cell_pool", 0).to_le_bytes());
                for name in ["radius", "t_n", "t_d"] {
                    def.extend(f(name, 0));
                }
                let (cap, cc) = (
                    u("bucket_capacity", 0) as usize,
                    u("cell_capacity", 0) as usize,
                );
                let t = 1usize << u("table_log2", 0);
                insts.push((
                    id,
                    Inst {
                        def,
                        transform: None,
                        entries: vec![(u32::MAX, u32::MAX); t * cap],
                        cap,
                        words: vec![0; u("cell_pool", 0) as usize * cc],
                        cell_capacity: cc,
                    },
                ));
            }
            kind => {
                let inst = &mut insts.iter_mut().find(|(i, _)| *i == id).unwrap().1;
                match kind {
                    "transform" => {
                        let mut t = u("seq", 0).to_le_bytes().to_vec();
                        (0..12).for_each(|k| t.extend(f("matrix", k)));
                        inst.transform = Some(t);
                    }
                    "bucket" => {
                        let b: usize = w[2].parse().unwrap();
                        let slot = (b * inst.cap..(b + 1) * inst.cap)
                            .find(|&i| inst.entries[i].0 == u32::MAX)
                            .unwrap();
                        inst.entries[slot] = (u("key", 0), u("cell", 0));
                    }
                    "word" => {
                        let i = u("cell", 0) as usize * inst.cell_capacity + u("slot", 0) as usize;
                        inst.words[i] = u32::from_str_radix(field("slot", 1), 16).unwrap();
                    }
                    other => panic!("state line {other}"),
                }
            }
        }
    }
    insts.sort_by_key(|(id, _)| *id);
    let mut bytes = sequence.to_le_bytes().to_vec();
    bytes.extend((insts.len() as u32).to_le_bytes());
    for (id, i) in &insts {
        bytes.extend(id.to_le_bytes());
        bytes.extend(&i.def);
        match &i.transform {
            Some(t) => {
                bytes.push(1);
                bytes.extend(t);
            }
            None => bytes.push(0),
        }
        for (k, c) in &i.entries {
            bytes.extend(k.to_le_bytes());
            bytes.extend(c.to_le_bytes());
        }
        i.words.iter().for_each(|x| bytes.extend(x.to_le_bytes()));
    }
    Some(crc32fast::hash(&bytes))
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
