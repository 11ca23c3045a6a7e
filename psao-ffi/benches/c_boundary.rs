//! What the C boundary costs: decode+apply of the codec bench's stream
//! (the test kit's synthetic scene, 120 frames, the paper's thresholds, as
//! `psao-codec`'s `codec_throughput`) through the C API against the Rust
//! API, in one run, passes interleaved, as ratios.
//!
//! Both sides do what a renderer does per frame: receive the frame, read
//! the list of changed ranges, clear it. The C side calls the exported
//! `extern "C"` functions, the code a C caller runs (pointer checks, panic
//! guard, event and change conversion, the error slot); only the call
//! instruction is Rust's rather than C's, with the same C ABI.
//!
//! `cargo bench -p psao-ffi --bench c_boundary`
#![allow(unsafe_code)]

use std::hint::black_box;
use std::ptr::null_mut;
use std::time::{Duration, Instant};

use psao_codec::{Compression, Decoder, Event, Limits};
use psao_ffi::*;
use psao_tests::synthetic::{BENCH_FRAMES, BenchStream};

/// The Rust API: returns the change items seen (so nothing is optimized out).
fn rust_pass(keyframe: &[u8], deltas: &[Vec<u8>]) -> (Duration, usize) {
    let mut d = Decoder::new(Limits::default());
    d.receive(keyframe).expect("keyframe");
    d.mirror_mut().clear_changes();
    let mut items = 0;
    let t = Instant::now();
    for f in deltas {
        let e = d.receive(f).expect("valid frame");
        assert!(matches!(e, Event::Applied { .. }));
        let c = d.mirror().changes();
        items += c.items.len() + c.all as usize;
        black_box(&c.items);
        d.mirror_mut().clear_changes();
    }
    (t.elapsed(), items)
}

/// The C API, as a C renderer calls it, with a reused change buffer.
fn c_pass(
    keyframe: &[u8],
    deltas: &[Vec<u8>],
    changes: &mut Vec<psao_change>,
) -> (Duration, usize) {
    let mut d = null_mut();
    let mut ev = psao_event {
        kind: psao_event_kind::PSAO_EVENT_STALE,
        sequence: 0,
        keyframe: 0,
        have_valid: 0,
        have: 0,
        base: 0,
    };
    // SAFETY: `d`, `ev` are live locals; `keyframe` holds its length.
    unsafe {
        assert_eq!(
            psao_decoder_new(std::ptr::null(), &mut d),
            psao_result::PSAO_OK
        );
        assert_eq!(
            psao_decoder_receive(d, keyframe.as_ptr(), keyframe.len(), &mut ev),
            psao_result::PSAO_OK
        );
        psao_decoder_clear_changes(d);
    }
    let mut items = 0;
    let t = Instant::now();
    for f in deltas {
        let (mut len, mut all) = (0usize, 0u8);
        // SAFETY: `d` is live; `f` holds its length; `changes` holds its
        // capacity; the outputs are live locals.
        unsafe {
            let r = psao_decoder_receive(d, f.as_ptr(), f.len(), &mut ev);
            assert!(r == psao_result::PSAO_OK && ev.kind == psao_event_kind::PSAO_EVENT_APPLIED);
            let mut r =
                psao_decoder_changes(d, changes.as_mut_ptr(), changes.len(), &mut len, &mut all);
            if r == psao_result::PSAO_ERROR_BUFFER_TOO_SHORT {
                changes.resize(len, changes[0]);
                r = psao_decoder_changes(
                    d,
                    changes.as_mut_ptr(),
                    changes.len(),
                    &mut len,
                    &mut all,
                );
            }
            assert_eq!(r, psao_result::PSAO_OK);
            psao_decoder_clear_changes(d);
        }
        items += len + all as usize;
        black_box(&changes[..len]);
    }
    let elapsed = t.elapsed();
    // SAFETY: made above, freed once.
    unsafe { psao_decoder_free(d) };
    (elapsed, items)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let reps: usize = std::env::var("PSAO_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(31);
    println!(
        "decode+apply of the codec bench stream ({BENCH_FRAMES} frames), Rust API vs C API, {reps} interleaved passes, medians"
    );
    println!();
    println!(
        "| compression | frames | updated points | Rust µs/frame | C µs/frame | C / Rust (median of pair ratios) | min pair ratio | max pair ratio |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, compression, level) in [
        ("none", Compression::None, 0),
        ("lz4", Compression::Lz4, 0),
        ("zstd-3", Compression::Zstd, 3),
    ] {
        let BenchStream {
            keyframe,
            deltas,
            points,
        } = BenchStream::encode(compression, level);
        let mut changes = vec![
            psao_change {
                kind: psao_change_kind::PSAO_CHANGE_DEFINED,
                instance: 0,
                start: 0,
                end: 0,
            };
            64
        ];
        // Warm both paths, and check they see the same changes.
        let (_, rust_items) = rust_pass(&keyframe, &deltas);
        let (_, c_items) = c_pass(&keyframe, &deltas, &mut changes);
        assert_eq!(rust_items, c_items);
        let (mut rust, mut c, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        for rep in 0..reps {
            let (r, k) = if rep % 2 == 0 {
                let r = rust_pass(&keyframe, &deltas).0;
                (r, c_pass(&keyframe, &deltas, &mut changes).0)
            } else {
                let k = c_pass(&keyframe, &deltas, &mut changes).0;
                (rust_pass(&keyframe, &deltas).0, k)
            };
            let per = |d: Duration| d.as_secs_f64() * 1e6 / deltas.len() as f64;
            rust.push(per(r));
            c.push(per(k));
            ratios.push(k.as_secs_f64() / r.as_secs_f64());
        }
        let (lo, hi) = (
            ratios.iter().copied().fold(f64::INFINITY, f64::min),
            ratios.iter().copied().fold(0.0, f64::max),
        );
        println!(
            "| {name} | {} | {points} | {:.2} | {:.2} | {:.3} | {lo:.3} | {hi:.3} |",
            deltas.len(),
            median(rust),
            median(c),
            median(ratios)
        );
    }
}
