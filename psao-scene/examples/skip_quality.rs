//! What skipping costs in quality: two servers stream the same scene in
//! lockstep, one re-tracing only what motion reaches, one re-tracing every
//! point every frame. Each feeds its own client; after every frame both
//! clients reconstruct AO (paper eq. 2-4) at every point of the scene, and
//! the difference is reported as PSNR, next to the rays each server cast.
//!
//! `cargo run --release -p psao-scene --example skip_quality -- [--frames N] [--gltf PATH]`

use std::time::Instant;

use psao_codec::{Decoder, Limits, reconstruct_ao, world_to_local};
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
    let frames: u32 = arg("--frames", 240);
    let gltf: String = arg("--gltf", String::new());
    let scene = if gltf.is_empty() {
        default_scene()
    } else {
        let mut s = load_gltf(std::path::Path::new(&gltf)).unwrap_or_else(|e| {
            eprintln!("error: {e}");
            std::process::exit(2)
        });
        // Stand it on a floor so its motion has something to shade.
        s.add(
            Mesh::quad(
                glam::Vec3::new(-3.0, 0.0, -3.0),
                glam::Vec3::Z * 6.0,
                glam::Vec3::X * 6.0,
            ),
            glam::Affine3A::IDENTITY,
        );
        s
    };
    let make = |skip: bool| {
        Pipeline::new(
            scene.clone(),
            PipelineConfig {
                skip,
                ..PipelineConfig::default()
            },
        )
        .unwrap_or_else(|e| {
            eprintln!("error: {e}");
            std::process::exit(2)
        })
    };
    let (mut fast, mut full) = (make(true), make(false));
    let mut clients = [
        Decoder::new(Limits::default()),
        Decoder::new(Limits::default()),
    ];
    for (c, p) in clients.iter_mut().zip([&mut fast, &mut full]) {
        c.receive(&p.keyframe().expect("keyframe").bytes)
            .expect("keyframe applies");
    }
    let (mut rays, mut traced) = ([0u64; 2], [0u64; 2]);
    let (mut sq, mut probes, mut worst, mut identical) = (0f64, 0u64, 0f32, 0u32);
    let t = Instant::now();
    for _ in 0..frames {
        for (k, p) in [&mut fast, &mut full].into_iter().enumerate() {
            let (frame, r) = p.step(1.0 / 60.0).expect("step");
            rays[k] += r.rays;
            traced[k] += r.traced;
            if let Some(f) = frame {
                clients[k].receive(&f.bytes).expect("frame applies");
            }
        }
        let (a, b) = (clients[0].mirror(), clients[1].mirror());
        let same = (0..fast.instance_count() as u32).all(|i| {
            let (x, y) = (a.instance(i), b.instance(i));
            x.map(|m| (m.words(), m.buckets())) == y.map(|m| (m.words(), m.buckets()))
        });
        identical += same as u32;
        // Reconstruct at every point of the scene, as both clients see it.
        for i in 0..fast.instance_count() {
            let (Some(ma), Some(mb)) = (a.instance(i as u32), b.instance(i as u32)) else {
                continue;
            };
            // Where clients look the points up (bind space for deforming
            // instances, whose lookup needs no transform).
            let (pos, nrm) = fast.stored_points(i).expect("instance");
            let to_world = if ma.def().bind_space() {
                glam::Affine3A::IDENTITY
            } else {
                fast.transform(i).expect("instance")
            };
            for (&p, &n) in pos.iter().zip(nrm) {
                let (wp, wn) = (to_world.transform_point3(p), to_world.transform_vector3(n));
                let Some((x, nx)) = world_to_local(&to_world, wp, wn) else {
                    continue;
                };
                let d = reconstruct_ao(ma, x, nx) - reconstruct_ao(mb, x, nx);
                sq += (d as f64) * (d as f64);
                worst = worst.max(d.abs());
                probes += 1;
            }
        }
    }
    let mse = sq / probes.max(1) as f64;
    let psnr = if mse == 0.0 {
        "infinite (identical)".to_string()
    } else {
        format!("{:.2} dB", 10.0 * (1.0 / mse).log10())
    };
    let n = frames as f64;
    println!(
        "{}: {frames} frames at 60 Hz, {:.1} s wall",
        if gltf.is_empty() {
            "default scene"
        } else {
            &gltf
        },
        t.elapsed().as_secs_f64()
    );
    println!(
        "  points traced per frame  skip {:.0}, every point {:.0} ({:.2}% of the rays)",
        traced[0] as f64 / n,
        traced[1] as f64 / n,
        100.0 * rays[0] as f64 / rays[1].max(1) as f64
    );
    println!("  client mirrors           identical after {identical} of {frames} frames");
    println!(
        "  reconstruction           PSNR of skip against every point {psnr}, worst AO difference {worst:.4} over {probes} probes"
    );
}
