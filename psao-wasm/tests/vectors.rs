//! The bindings against spec/vectors, natively: every frame of every
//! vector gives the recorded outcome through `WasmDecoder::receive` (error
//! classes by their text), and the mirror ends at the recorded digest. CI
//! runs the same replay in WebAssembly on Node (`tests/node/replay.mjs`).

use std::path::PathBuf;

use psao_wasm::{Outcome, WasmDecoder};

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// The outcome of a frame as a vector's `expect` line writes it.
fn outcome(r: &Result<psao_wasm::Received, String>) -> String {
    match r {
        Ok(x) if x.kind == Outcome::Applied => format!(
            "applied {} {}",
            x.sequence,
            if x.keyframe { "keyframe" } else { "delta" }
        ),
        Ok(x) if x.kind == Outcome::Stale => "stale".into(),
        Ok(x) if x.kind == Outcome::NeedKeyframe => "need_keyframe".into(),
        Ok(x) => format!("kind {:?}", x.kind),
        Err(e) => format!("error {}", e.split(':').next().unwrap_or("")),
    }
}

#[test]
fn every_vector_replays_through_the_bindings() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../spec/vectors");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "txt"))
        .collect();
    files.sort();
    assert!(files.len() >= 60);
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let mut d = WasmDecoder::with_default_limits();
        for l in text.lines().filter_map(|l| l.strip_prefix("limit ")) {
            let (n, v) = l.split_once(' ').unwrap();
            assert!(
                d.set_limit(n, v.parse().unwrap()),
                "{}: {l}",
                path.display()
            );
        }
        let mut last = None;
        for line in text.lines() {
            if let Some(hex) = line.strip_prefix("frame ") {
                last = Some(d.receive(&unhex(hex)));
            } else if let Some(want) = line.strip_prefix("expect ") {
                let got = outcome(last.as_ref().expect("a frame before expect"));
                assert_eq!(got, want, "{}", path.display());
            } else if let Some(want) = line.strip_prefix("digest ") {
                let got = d.digest().map_or("none".into(), |x| format!("{x:08x}"));
                assert_eq!(got, want, "{}", path.display());
            }
        }
    }
}

#[test]
fn changes_list_what_a_delta_wrote() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../spec/vectors/03-delta-xor-ao-free.txt"
    ))
    .unwrap();
    let frames: Vec<Vec<u8>> = text
        .lines()
        .filter_map(|l| l.strip_prefix("frame "))
        .map(unhex)
        .collect();
    let mut d = WasmDecoder::new(1 << 20, 1 << 22, f64::INFINITY).unwrap();
    assert!(WasmDecoder::new(1 << 20, 1 << 22, f64::NAN).is_err());
    assert!(WasmDecoder::new(1 << 20, 1 << 22, 0.0).is_err());
    d.receive(&frames[0]).unwrap();
    assert_eq!(d.take_changes()[0], 1, "a keyframe: upload everything");
    assert_eq!(d.take_changes(), vec![0], "nothing since");
    d.receive(&frames[1]).unwrap();
    let c = d.take_changes();
    assert_eq!(c[0], 0);
    assert!(c.len() > 1 && (c.len() - 1).is_multiple_of(4), "{c:?}");
    assert_eq!(c[1], psao_wasm::change_kind::WORDS, "{c:?}");
    assert_eq!(d.instances(), vec![1]);
    assert!(
        !d.set_limit("max_instances", 4.0),
        "not once the mirror holds a state"
    );
    assert!(!d.words(1).is_empty());
    assert!(d.words(7).is_empty());
}
