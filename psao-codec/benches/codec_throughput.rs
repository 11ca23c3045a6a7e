//! Codec throughput and bit rate on a synthetic update stream
//! (the test kit's `psao_tests::synthetic`): AO drifting over a 16 m floor and a
//! wall, and a box moving between cells.
//!
//! Measured in one run, side by side, as ratios:
//! - encode of the deltas (points/s, MB/s) for none / lz4 / zstd, against
//!   raw compression of the same payloads;
//! - decode + apply (points/s, MB/s) against memcpy of the same frame bytes
//!   and against raw decompression of the same payloads;
//! - bytes per updated point of v1 against the paper's scheme (full 7-word
//!   cells XORed against the previous words, 8-entry buckets, zstd level 15)
//!   on the same dirty sets.
//!
//! Not a criterion/divan bench on purpose: the targets are ratios of
//! measurements taken in the same run, which those harnesses do not expose
//! to the program. Each figure is the median of repeated timed passes.
//!
//! `cargo bench -p psao-codec --bench codec_throughput`

use std::hint::black_box;
use std::time::{Duration, Instant};

use psao_codec::{
    Compression, Decoder, DirtySet, EncodedFrame, Encoder, EncoderConfig, Event, GridTable, Limits,
    Thresholds,
};
use psao_tests::synthetic::Synthetic;

/// The frames of the stream: the test kit's, as every codec bench's.
const FRAMES: usize = psao_tests::synthetic::BENCH_FRAMES;

/// One server frame: the table after the frame's updates and its dirty set.
struct Step {
    table: GridTable,
    dirty: DirtySet,
    changed_points: usize,
}

fn record_stream() -> (GridTable, Vec<Step>, usize) {
    let mut s = Synthetic::new(7);
    s.table.take_dirty();
    let start = s.table.clone();
    let th = Thresholds::default();
    let mut steps = Vec::new();
    for _ in 0..FRAMES {
        s.step(&th);
        let dirty = s.table.take_dirty();
        let cap = s.table.def().cell_capacity as usize;
        let changed_points = dirty
            .cells
            .iter()
            .map(|d| {
                let new = s.table.cell(d.cell);
                (0..cap).filter(|&i| new[i] != d.old[i]).count()
            })
            .sum();
        steps.push(Step {
            table: s.table.clone(),
            dirty,
            changed_points,
        });
    }
    let points = s.points();
    (start, steps, points)
}

fn encode_all(enc: &mut Encoder, steps: &[Step]) -> Vec<EncodedFrame> {
    steps
        .iter()
        .filter_map(|st| {
            let mut f = enc.delta();
            f.dirty_set(&st.table, &st.dirty);
            f.finish().expect("encode")
        })
        .collect()
}

/// Median wall time of `reps` runs of `f`.
fn time(reps: usize, mut f: impl FnMut()) -> Duration {
    f();
    let mut t: Vec<Duration> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed()
        })
        .collect();
    t.sort();
    t[reps / 2]
}

fn keyframe(start: &GridTable, config: EncoderConfig) -> EncodedFrame {
    let mut enc = Encoder::new(config);
    let mut kf = enc.keyframe();
    kf.snapshot(start).expect("no pending changes");
    kf.finish().expect("encode").expect("keyframe")
}

/// The paper's scheme on the same dirty sets: per dirty bucket its index
/// and 8 entries (key, cell), per dirty cell its index and all 7 words XORed
/// against the previous ones; the frame compressed with zstd level 15.
fn paper_bytes(steps: &[Step]) -> usize {
    let mut total = 0;
    for st in steps {
        let mut raw = Vec::new();
        let cap = st.table.def().bucket_capacity as usize;
        for &b in &st.dirty.buckets {
            raw.extend_from_slice(&b.to_le_bytes());
            let entries = &st.table.buckets()[b as usize * cap..(b as usize + 1) * cap];
            for e in entries {
                raw.extend_from_slice(&e.key.to_le_bytes());
                raw.extend_from_slice(&e.cell.to_le_bytes());
            }
        }
        for d in &st.dirty.cells {
            raw.extend_from_slice(&d.cell.to_le_bytes());
            for (n, o) in st.table.cell(d.cell).iter().zip(d.old) {
                raw.extend_from_slice(&(n ^ o).to_le_bytes());
            }
        }
        if !raw.is_empty() {
            total += zstd::bulk::compress(&raw, 15).expect("zstd").len();
        }
    }
    total
}

fn raw_decompress(frames: &[EncodedFrame], out: &mut [u8]) {
    for f in frames {
        let h = psao_codec::wire::FrameHeader::parse(&f.bytes).expect("header");
        let payload = &f.bytes[psao_codec::wire::HEADER_LEN..];
        let n = h.uncompressed_len as usize;
        match h.compression {
            Compression::None => out[..payload.len()].copy_from_slice(payload),
            Compression::Lz4 => {
                lz4_flex::block::decompress_into(payload, &mut out[..n]).expect("lz4");
            }
            Compression::Zstd => {
                zstd::bulk::decompress_to_buffer(payload, &mut out[..n]).expect("zstd");
            }
        }
    }
}

fn main() {
    let reps = std::env::var("PSAO_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(21);
    let (start, steps, points) = record_stream();
    let changed: usize = steps.iter().map(|s| s.changed_points).sum();
    let mut final_mirror: Option<psao_codec::Mirror> = None;
    println!(
        "synthetic stream: {points} points, {FRAMES} frames, {changed} updated points ({:.0}/frame), {reps} reps, median",
        changed as f64 / FRAMES as f64
    );

    println!();
    println!(
        "| compression | frame bytes | payload bytes | encode Mpts/s | encode MB/s (payload) | encode / raw compress | decode+apply Mpts/s | decode+apply MB/s (wire) | memcpy / decode+apply | raw decompress / decode+apply |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (name, compression, level) in [
        ("none", Compression::None, 0),
        ("lz4", Compression::Lz4, 0),
        ("zstd-3", Compression::Zstd, 3),
    ] {
        let config = EncoderConfig {
            compression,
            zstd_level: level,
            checksum: false,
            ..Default::default()
        };
        let mut enc = Encoder::new(config);
        let frames = encode_all(&mut enc, &steps);
        let wire: usize = frames.iter().map(|f| f.bytes.len()).sum();
        let payload: usize = frames.iter().map(|f| f.stats.payload_bytes as usize).sum();
        let sent: usize = frames.iter().map(|f| f.stats.points as usize).sum();

        let t_encode = time(reps, || {
            let mut enc = Encoder::new(config);
            black_box(encode_all(&mut enc, &steps));
        });
        // Raw compression of the same payloads (re-encoded uncompressed to get them).
        let plain = encode_all(
            &mut Encoder::new(EncoderConfig {
                compression: Compression::None,
                ..config
            }),
            &steps,
        );
        let t_compress = time(reps, || {
            for f in &plain {
                let p = &f.bytes[psao_codec::wire::HEADER_LEN..];
                match compression {
                    Compression::None => {
                        black_box(p.to_vec());
                    }
                    Compression::Lz4 => {
                        black_box(lz4_flex::block::compress(p));
                    }
                    Compression::Zstd => {
                        black_box(zstd::bulk::compress(p, level).expect("zstd"));
                    }
                }
            }
        });

        // A fresh decoder per pass: a keyframe re-sent to a decoder that is
        // already past it is (correctly) stale, and so are the deltas.
        let kf = keyframe(&start, config);
        let apply_all = |with_deltas: bool| {
            let mut decoder = Decoder::new(Limits::default());
            let applied = |e| matches!(e, Ok(Event::Applied { .. }));
            assert!(applied(decoder.receive(&kf.bytes)), "keyframe applies");
            if with_deltas {
                for f in &frames {
                    assert!(applied(decoder.receive(&f.bytes)), "delta applies");
                    // A renderer uploads the changed ranges, then clears them.
                    black_box(decoder.mirror().changes());
                    decoder.mirror_mut().clear_changes();
                }
            }
            decoder
        };
        let last = apply_all(true);
        final_mirror.get_or_insert_with(|| last.mirror().clone());
        assert!(
            last.mirror().instance(1).map(|m| m.words()) == Some(steps[FRAMES - 1].table.words())
        );
        let t_decode = time(reps, || {
            black_box(apply_all(true));
        })
        .saturating_sub(time(reps, || {
            black_box(apply_all(false));
        }));
        let mut sink = vec![0u8; wire];
        let t_memcpy = time(reps, || {
            let mut at = 0;
            for f in &frames {
                sink[at..at + f.bytes.len()].copy_from_slice(&f.bytes);
                at += f.bytes.len();
            }
            black_box(&sink);
        });
        let mut out = vec![
            0u8;
            frames
                .iter()
                .map(|f| f.stats.payload_bytes as usize)
                .max()
                .unwrap_or(0)
        ];
        let t_raw = time(reps, || {
            raw_decompress(&frames, &mut out);
            black_box(&out);
        });

        let s = |d: Duration| d.as_secs_f64();
        println!(
            "| {name} | {wire} | {payload} | {:.1} | {:.0} | {:.3} | {:.1} | {:.0} | {:.3} | {:.3} |",
            sent as f64 / s(t_encode) / 1e6,
            payload as f64 / s(t_encode) / 1e6,
            s(t_compress) / s(t_encode),
            sent as f64 / s(t_decode) / 1e6,
            wire as f64 / s(t_decode) / 1e6,
            s(t_memcpy) / s(t_decode),
            s(t_raw) / s(t_decode),
        );
    }

    // The mirror digest (spec/wire-format.md 7.5) of the final state,
    // against copying as many bytes.
    if let Some(m) = &final_mirror {
        let bytes = m.bytes() as usize;
        let t_digest = time(reps, || {
            black_box(m.digest());
        });
        let src = vec![1u8; bytes];
        let mut dst = vec![0u8; bytes];
        let t_copy = time(reps, || {
            dst.copy_from_slice(black_box(&src));
            black_box(&dst);
        });
        println!();
        println!(
            "mirror digest: {bytes} bytes in {:.1} us ({:.2} GB/s); memcpy of as many bytes / digest: {:.3}",
            t_digest.as_secs_f64() * 1e6,
            bytes as f64 / t_digest.as_secs_f64() / 1e9,
            t_copy.as_secs_f64() / t_digest.as_secs_f64()
        );
    }

    println!();
    println!("bytes per updated point, same {FRAMES} dirty sets ({changed} updated points):");
    println!();
    println!("| scheme | bytes | bytes / updated point | vs paper scheme |");
    println!("|---|---|---|---|");
    let paper = paper_bytes(&steps);
    println!(
        "| paper: 7-word XOR cells + 8-entry buckets, zstd-15 | {paper} | {:.3} | 1.00 |",
        paper as f64 / changed as f64
    );
    for (name, compression, level) in [
        ("v1, zstd-15", Compression::Zstd, 15),
        ("v1, zstd-3", Compression::Zstd, 3),
        ("v1, lz4", Compression::Lz4, 0),
        ("v1, none", Compression::None, 0),
    ] {
        let config = EncoderConfig {
            compression,
            zstd_level: level,
            checksum: false,
            ..Default::default()
        };
        let bytes: usize = encode_all(&mut Encoder::new(config), &steps)
            .iter()
            .map(|f| f.bytes.len())
            .sum();
        println!(
            "| {name} | {bytes} | {:.3} | {:.2} |",
            bytes as f64 / changed as f64,
            bytes as f64 / paper as f64
        );
    }
}
