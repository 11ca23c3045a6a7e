//! The codec end to end, in one process, on the synthetic scene of
//! the test kit (`psao_tests::synthetic`): 10 s at 60 Hz of a box sliding over a
//! floor with AO drifting. A server table streams deltas (zstd, checksum) to
//! client A; client B joins late from a keyframe; client A loses a frame,
//! asks for a keyframe and resyncs. At the end both mirrors must equal the
//! server's table, and AO reconstructed from a mirror at every point is
//! compared with the value the server traced.
//!
//! `cargo run --release -p psao-codec --example codec_stream`

use std::time::{Duration, Instant};

use psao_codec::{Decoder, Encoder, EncoderConfig, Event, Limits, Thresholds, reconstruct_ao};
use psao_tests::synthetic::Synthetic;

const FRAMES: u32 = 600;
const HZ: f64 = 60.0;

fn main() {
    let mut scene = Synthetic::new(7);
    scene.table.take_dirty();
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut a = Decoder::new(Limits::default());
    let mut b: Option<Decoder> = None;
    let th = Thresholds::default();
    let keyframe = |enc: &mut Encoder, scene: &Synthetic| {
        let mut kf = enc.keyframe();
        kf.snapshot(&scene.table).expect("nothing pending");
        kf.finish().expect("encode").expect("keyframe")
    };
    let kf = keyframe(&mut enc, &scene);
    a.receive(&kf.bytes).expect("keyframe");
    println!(
        "synthetic scene: {} points, keyframe {} bytes ({:.2} bytes/point)",
        scene.points(),
        kf.bytes.len(),
        kf.bytes.len() as f64 / scene.points() as f64
    );
    let (mut bytes, mut sent_points, mut updated, mut frames) = (0usize, 0u64, 0usize, 0u32);
    let (mut t_update, mut t_encode, mut t_decode) =
        (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let (mut resyncs, mut keyframe_bytes) = (0u32, 0usize);
    for f in 1..=FRAMES {
        let t0 = Instant::now();
        updated += scene.step(&th);
        let t1 = Instant::now();
        let mut d = enc.delta();
        d.changes(&mut scene.table);
        let frame = d.finish().expect("encode");
        let t2 = Instant::now();
        t_update += t1 - t0;
        t_encode += t2 - t1;
        let Some(frame) = frame else { continue };
        frames += 1;
        bytes += frame.bytes.len();
        sent_points += frame.stats.points as u64;
        if let Some(b) = &mut b {
            let event = b.receive(&frame.bytes).expect("valid frame");
            assert!(
                matches!(event, Event::Applied { .. }),
                "client B: {event:?}"
            );
        }
        if f == 400 {
            // Client A loses this frame: the next one reports a gap.
            continue;
        }
        let t3 = Instant::now();
        let event = a.receive(&frame.bytes).expect("valid frame");
        t_decode += t3.elapsed();
        if let Event::NeedKeyframe { .. } = event {
            let kf = keyframe(&mut enc, &scene);
            keyframe_bytes += kf.bytes.len();
            resyncs += 1;
            assert!(matches!(
                a.receive(&kf.bytes),
                Ok(Event::Applied { keyframe: true, .. })
            ));
        }
        if f == 300 {
            let kf = keyframe(&mut enc, &scene);
            keyframe_bytes += kf.bytes.len();
            let mut late = Decoder::new(Limits::default());
            late.receive(&kf.bytes).expect("keyframe");
            b = Some(late);
        }
    }
    let b = b.expect("client B joined");
    for (name, client) in [("A", &a), ("B", &b)] {
        let m = client.mirror().instance(1).expect("instance");
        assert!(
            m.words() == scene.table.words(),
            "client {name}: words differ"
        );
        assert!(
            m.buckets() == scene.table.buckets(),
            "client {name}: buckets differ"
        );
    }
    let m = a.mirror().instance(1).expect("instance");
    let (mut err_sum, mut err_max, mut n) = (0f64, 0f32, 0usize);
    // A sent point is at most 8/255 stale (the update threshold) plus 1/510
    // of quantization; count the points beyond that and why.
    let bound = 8.0 / 255.0 + 1.0 / 510.0 + 1e-4;
    let (mut beyond, mut beyond_dropped) = (0usize, 0usize);
    for i in 0..scene.points() {
        let (p, normal, ao) = scene.point(i);
        let e = (reconstruct_ao(m, p, normal) - ao).abs();
        err_sum += e as f64;
        if e > err_max && std::env::var("PSAO_DEBUG").is_ok() {
            eprintln!(
                "point {i} at {p:?} n {normal:?}: server {ao} mirror {}",
                reconstruct_ao(m, p, normal)
            );
        }
        err_max = err_max.max(e);
        if e > bound {
            beyond += 1;
            if matches!(
                scene.table.placement(i as u32),
                psao_codec::Placement::Dropped(_)
            ) {
                beyond_dropped += 1;
            }
        }
        n += 1;
    }
    let secs = FRAMES as f64 / HZ;
    let stats = scene.table.stats();
    println!("{FRAMES} server frames at {HZ} Hz ({secs} s): {frames} sent, none empty");
    println!(
        "  points set        {:.0} per frame (paper thresholds; dropped points retry), {:.0} sent per frame",
        updated as f64 / FRAMES as f64,
        sent_points as f64 / frames as f64
    );
    println!(
        "  bit rate          {:.2} Mbit/s, {:.2} bytes per sent point",
        bytes as f64 * 8.0 / secs / 1e6,
        bytes as f64 / sent_points as f64
    );
    println!(
        "  keyframes         {} bytes for 1 late join and {resyncs} resync after a lost frame",
        keyframe_bytes
    );
    println!(
        "  server ms/frame   {:.3} update (trace stand-in), {:.3} encode",
        t_update.as_secs_f64() * 1e3 / FRAMES as f64,
        t_encode.as_secs_f64() * 1e3 / FRAMES as f64
    );
    println!(
        "  client ms/frame   {:.3} decode+apply",
        t_decode.as_secs_f64() * 1e3 / frames as f64
    );
    println!(
        "  table             {} points stored, {} dropped now, {} cells; drop events: {} cell full, {} bucket full, {} out of grid",
        stats.stored,
        stats.dropped,
        stats.cells,
        stats.cell_overflow,
        stats.bucket_overflow,
        stats.out_of_grid
    );
    println!("  mirrors A and B   equal to the server table");
    println!(
        "  reconstruction    |AO(mirror) - AO(server)| at every point: mean {:.4}, max {:.4}",
        err_sum / n as f64,
        err_max
    );
    println!(
        "                    {beyond} of {n} points beyond threshold + quantization ({bound:.4}), {beyond_dropped} of them dropped by overflow"
    );
}
