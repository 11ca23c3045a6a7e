//! Differential tests of the decoder (issue 16): psao-codec's frame layer
//! against the independent reference of `psao_tests::reference`, on every
//! frame of spec/vectors and on thousands of mutations of them, of their
//! payloads compressed with LZ4 and zstd, and of the compressed bytes
//! themselves (wrapped in correct headers, so the mutations reach the
//! decompressors). A disagreement means one of the two breaks the spec;
//! the fuzz target `decode_differential` runs the same comparison on any
//! bytes.

use psao_codec::Limits;
use psao_tests::reference::{compare, frame_around, frame_layer};
use psao_tests::synthetic::Rng;

fn vector_frames() -> Vec<Vec<u8>> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../spec/vectors");
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "txt"))
        .collect();
    paths.sort();
    let mut frames = Vec::new();
    for p in paths {
        for line in std::fs::read_to_string(&p).unwrap().lines() {
            if let Some(hex) = line.strip_prefix("frame ") {
                frames.push(
                    (0..hex.len())
                        .step_by(2)
                        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                        .collect(),
                );
            }
        }
    }
    frames
}

/// A few mutations of `f`: flipped bits, set bytes, cuts and insertions.
fn mutate(f: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut m = f.to_vec();
    let pick = |rng: &mut Rng, n: usize| (rng.next_f32() * n as f32) as usize % n.max(1);
    for _ in 0..1 + pick(rng, 3) {
        match pick(rng, 4) {
            0 if !m.is_empty() => {
                let i = pick(rng, m.len());
                m[i] ^= 1 << pick(rng, 8);
            }
            1 if !m.is_empty() => {
                let i = pick(rng, m.len());
                m[i] = [0, 0xFF, 0x80, 1][pick(rng, 4)];
            }
            2 if !m.is_empty() => {
                let n = pick(rng, m.len());
                m.truncate(n);
            }
            _ => {
                let i = pick(rng, m.len() + 1);
                m.insert(i, pick(rng, 256) as u8);
            }
        }
    }
    m
}

#[test]
fn the_vectors_agree_with_the_reference() {
    let limits = Limits::default();
    let frames = vector_frames();
    assert!(frames.len() > 60);
    for f in &frames {
        compare(f, &limits).unwrap();
    }
}

/// Frames the fuzz target `decode_differential` found the two disagreeing
/// on, once mended: the first (CI, 2026-12-07) is a zstd frame whose only
/// block is a compressed block of `Block_Size` 0, which libzstd's streaming
/// decoder took as an empty block (spec 3.2, vector 63).
#[test]
fn what_the_fuzzer_found_agrees() {
    let limits = Limits {
        max_payload_bytes: 1 << 20,
        ..Limits::default()
    };
    let hex = "5053414f010302000700000007000000010000000000000009000000\
               cad94fe928b52ffd0000050000";
    let frame: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    assert_eq!(frame_layer(&frame, &limits), Err("decompress"));
    compare(&frame, &limits).unwrap();
}

#[test]
fn mutated_frames_agree_with_the_reference() {
    let limits = Limits {
        max_frame_bytes: 4096,
        max_payload_bytes: 4096,
        max_messages: 64,
        ..Limits::default()
    };
    let mut rng = Rng::new(16);
    let mut classes = std::collections::BTreeMap::<&str, u32>::new();
    for f in vector_frames() {
        for _ in 0..300 {
            let m = mutate(&f, &mut rng);
            compare(&m, &limits).unwrap();
            *classes
                .entry(frame_layer(&m, &limits).err().unwrap_or("passes"))
                .or_default() += 1;
        }
    }
    // The mutations reached every frame-layer check.
    for class in [
        "bad_magic",
        "unsupported_version",
        "header_field",
        "truncated",
        "trailing_bytes",
        "checksum",
        "decompress",
        "passes",
    ] {
        assert!(
            classes.get(class).is_some_and(|&n| n > 0),
            "{class}: {classes:?}"
        );
    }
}

#[test]
fn mutated_compressed_payloads_agree_with_the_reference() {
    let limits = Limits::default();
    let mut rng = Rng::new(27);
    let (mut decoded, mut refused) = (0, 0);
    for f in vector_frames() {
        // The payload of every uncompressed, well-formed vector frame.
        if f.len() < 32 || f[6] != 0 || frame_layer(&f, &limits).is_err() {
            continue;
        }
        let payload = &f[32..];
        let n = payload.len() as u32;
        for (id, wire) in [
            (1u8, lz4_flex::block::compress(payload)),
            (2, zstd::bulk::compress(payload, 3).unwrap()),
        ] {
            compare(&frame_around(&wire, id, n, false), &limits).unwrap();
            for _ in 0..200 {
                let m = mutate(&wire, &mut rng);
                let frame = frame_around(&m, id, n, true);
                compare(&frame, &limits).unwrap();
                match frame_layer(&frame, &limits) {
                    Ok(_) => decoded += 1,
                    Err(_) => refused += 1,
                }
            }
        }
    }
    assert!(
        decoded > 100 && refused > 1000,
        "decoded {decoded}, refused {refused}"
    );
}
