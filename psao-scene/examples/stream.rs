//! The main job on the embedded default scene: a server traces AO for the
//! scene's points and streams 10 s at 60 Hz to a client in-process (real
//! frames, decoder and mirror). Prints per-stage times, points traced and
//! sent, bit rate, and checks the client's mirror against the server.
//!
//! With `--no-skip` the server re-traces every point every frame (the
//! baseline that skipping is measured against); `--frames N` and
//! `--density D` change the run.
//!
//! `cargo run --release -p psao-scene --example stream`

use std::time::Instant;

use psao_codec::{Decoder, Event, Limits};
use psao_scene::*;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let frames: u32 = arg("--frames", 600);
    let density: f32 = arg("--density", 64.0);
    let skip = !std::env::args().any(|a| a == "--no-skip");
    let (scene, motions) = default_scene();
    let config = PipelineConfig {
        density,
        skip,
        ..PipelineConfig::default()
    };
    let t = Instant::now();
    let mut server = Pipeline::new(scene, motions, config).expect("default scene");
    let setup = t.elapsed();
    let mut client = Decoder::new(Limits::default());
    let kf = server.keyframe().expect("keyframe");
    client.receive(&kf.bytes).expect("keyframe applies");
    let points: usize = (0..server.instance_count())
        .map(|i| server.points(i).map_or(0, |p| p.len()))
        .sum();
    println!(
        "default scene: {} instances, {points} points; setup (points, layout, first trace) {:.2} s; keyframe {} bytes",
        server.instance_count(),
        setup.as_secs_f64(),
        kf.bytes.len()
    );
    let mut sum = FrameReport::default();
    let mut sent = 0u32;
    let t = Instant::now();
    for _ in 0..frames {
        let (frame, r) = server.step(1.0 / 60.0).expect("step");
        sum.traced += r.traced;
        sum.rays += r.rays;
        sum.updated += r.updated;
        sum.bytes += r.bytes;
        sum.t_scene += r.t_scene;
        sum.t_trace += r.t_trace;
        sum.t_encode += r.t_encode;
        if let Some(f) = frame {
            sent += 1;
            let e = client.receive(&f.bytes).expect("valid frame");
            assert!(matches!(e, Event::Applied { .. }), "{e:?}");
        }
    }
    let wall = t.elapsed().as_secs_f64();
    let n = frames as f64;
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3 / n;
    for i in 0..server.instance_count() {
        let (t, m) = (
            server.table(i).expect("table"),
            client.mirror().instance(i as u32).expect("mirror"),
        );
        assert!(
            t.words() == m.words() && t.buckets() == m.buckets(),
            "instance {i} differs"
        );
    }
    println!(
        "{frames} frames at 60 Hz ({:.1} s of scene), {sent} sent, {wall:.2} s wall, skip {}",
        n / 60.0,
        if skip { "on" } else { "off" }
    );
    println!(
        "  points traced      {:.0} per frame ({:.1}% of {points})",
        sum.traced as f64 / n,
        100.0 * sum.traced as f64 / n / points as f64
    );
    println!(
        "  rays               {:.0} per frame, {:.2} Mrays/s while tracing",
        sum.rays as f64 / n,
        sum.rays as f64 / sum.t_trace.as_secs_f64().max(1e-9) / 1e6
    );
    println!(
        "  points sent        {:.0} per frame (past the thresholds; dropped points retry)",
        sum.updated as f64 / n
    );
    println!(
        "  bit rate           {:.3} Mbit/s",
        sum.bytes as f64 * 8.0 / (n / 60.0) / 1e6
    );
    println!(
        "  server ms/frame    {:.3} scene + BVH, {:.3} trace, {:.3} tables + encode",
        ms(sum.t_scene),
        ms(sum.t_trace),
        ms(sum.t_encode)
    );
    println!("  client mirror      equal to the server's tables");
}
