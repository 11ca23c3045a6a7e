//! Client time of the PSAO client's AO pass ([`psao_image`], and
//! [`psao_image_seen`] with the hidden test of spec/wire-format.md 7.3.1)
//! against SAO ([`sao`]) on the same G-buffers, side by side in one process, with
//! many images each: the issue 15 ratio (PSAO at most 1.5x SAO's client
//! time) with less spread than `psao bench`'s few frames.
//!
//! ```sh
//! cargo run --release -p psao-eval --example client_time -- [--gltf FILE | --scene default|cesium-man|hall] \
//!     [--density N] [--radius R] [--width W] [--height H] [--views V] [--rounds K] [--ticks T] [--evict-mib M]
//! ```
//!
//! `--density` is the paper's N (points kept per square metre, the bench's
//! `--densities`), 1024 by default; the server streams its keyframe and
//! `--ticks` (60) ticks to the in-process client (16 rays a point: the
//! AO's values do not change the client's work), which then draws `--views`
//! (8) views spread over the camera path, `--rounds` (5) times each, every
//! method alternating: warm (the method's own data in cache from its run
//! before, as a client drawing frame after frame) and cold (`--evict-mib`
//! (64) MiB written first, as after other work; on a processor whose
//! last-level cache holds more than that, raise it, or cold is warm).
//! Printed: the median milliseconds per image of each method, warm and
//! cold, and each PSAO pass over SAO.

use std::time::Instant;

use psao_codec::{Decoder, Limits};
use psao_eval::{GBuffer, PosedScene, SaoParams, View, psao_image, psao_image_seen, sao};
use psao_scene::*;
use rayon::prelude::*;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    match args.iter().position(|a| a == name) {
        None => default,
        Some(i) => args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| {
                eprintln!("error: {name} takes a value");
                std::process::exit(2)
            }),
    }
}

/// Writes `scratch` through, on every thread, so that what the last image
/// read is out of the caches (as after a server's step, or a renderer's
/// other work).
fn evict_cache(scratch: &mut [u8]) {
    scratch
        .par_chunks_mut(1 << 16)
        .for_each(|c| c.iter_mut().for_each(|b| *b = b.wrapping_add(1)));
    std::hint::black_box(&scratch);
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let gltf: String = arg("--gltf", String::new());
    let embedded: String = arg("--scene", "default".to_string());
    let n: f32 = arg("--density", 1024.0);
    let (width, height): (u32, u32) = (arg("--width", 320), arg("--height", 180));
    let views: u32 = arg("--views", 8);
    let rounds: usize = arg("--rounds", 5);
    let ticks: u32 = arg("--ticks", 60);
    // MiB written before each cold image.
    let evict: usize = arg("--evict-mib", 64);
    let mut scratch = vec![0u8; evict << 20];
    let scene = if !gltf.is_empty() {
        load_scene_file(std::path::Path::new(&gltf)).and_then(stage)?
    } else {
        match embedded.as_str() {
            "default" => default_scene(),
            "cesium-man" => cesium_man_scene(),
            "hall" => hall_scene(),
            other => {
                return Err(format!("unknown scene {other}: default, cesium-man or hall").into());
            }
        }
    };
    if views == 0 || rounds == 0 {
        return Err("--views and --rounds take 1 or more".into());
    }
    let camera = scene.camera.clone().ok_or("the scene has no camera path")?;
    let name = if gltf.is_empty() {
        embedded.clone()
    } else {
        gltf.clone()
    };
    let radius: f32 = arg("--radius", 0.6);
    let config = PipelineConfig {
        density: 2.0 * n,
        ao: AoParams {
            rays: 16,
            radius,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let mut server = Pipeline::new(scene.clone(), config)?;
    let mut client = Decoder::new(Limits::default());
    client.receive(&server.keyframe()?.bytes)?;
    for _ in 0..ticks {
        if let (Some(frame), _) = server.step(1.0 / 60.0)? {
            client.receive(&frame.bytes)?;
        }
    }
    let mirror = client.mirror();
    let points: usize = (0..server.instance_count())
        .filter_map(|i| server.points(i).map(|p| p.len()))
        .sum();
    let t = server.time();
    let posed = PosedScene::new(&scene, t)?;
    let span = camera.duration().max(1.0);
    let frames: Vec<(View, GBuffer)> = (0..views)
        .map(|v| {
            let view = View::new(camera.at(span * v as f32 / views as f32), width, height)?;
            let g = posed.gbuffer(&view);
            Ok((view, g))
        })
        .collect::<Result<_, SceneError>>()?;
    let params = SaoParams {
        radius,
        ..SaoParams::default()
    };
    // [PSAO, PSAO with the hidden test, SAO] x [warm, cold].
    let mut ms: [[Vec<f64>; 2]; 3] = Default::default();
    for _ in 0..rounds {
        for (view, g) in &frames {
            for (m, times) in ms.iter_mut().enumerate() {
                let run = || -> Result<(), SceneError> {
                    match m {
                        0 => psao_image(mirror, g).map(drop),
                        1 => psao_image_seen(mirror, g, view).map(drop),
                        _ => sao(&g.depth, view, &params).map(drop),
                    }
                };
                run()?;
                let s = Instant::now();
                run()?;
                times[0].push(s.elapsed().as_secs_f64() * 1e3);
                evict_cache(&mut scratch);
                let s = Instant::now();
                run()?;
                times[1].push(s.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    let covered = frames.iter().map(|(_, g)| g.covered()).sum::<usize>() / frames.len();
    let [[pw, pc], [hw, hc], [sw, sc]] = ms.map(|m| m.map(median));
    println!(
        "{name}: N = {n}, {points} points, {width}x{height}, {covered} pixels covered on average, {} threads, medians of {} images: PSAO {pw:.2} ms warm, {pc:.2} cold; PSAO with the hidden test {hw:.2} warm, {hc:.2} cold; SAO {sw:.2} warm, {sc:.2} cold; PSAO / SAO {:.2}x warm, {:.2}x cold; with the test / SAO {:.2}x warm, {:.2}x cold",
        rayon::current_num_threads(),
        rounds * frames.len(),
        pw / sw,
        pc / sc,
        hw / sw,
        hc / sc,
    );
    Ok(())
}
