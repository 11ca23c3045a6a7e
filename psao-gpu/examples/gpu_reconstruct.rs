//! Client reconstruction at 1920x1080 on the default scene: the WGSL pass
//! on the GPU (wgpu; lavapipe runs it on this machine's CPU cores) against
//! psao-codec's CPU reconstruction and the CPU SAO baseline, same G-buffer,
//! same run. The GPU time includes uploading the G-buffer and reading the
//! image back (a renderer keeps both on the GPU); the upload of the mirror
//! is timed apart.
//!
//! `cargo run --release -p psao-gpu --example gpu_reconstruct [-- --density 2048 --reps 3]`

use std::time::Instant;

use psao_codec::{Decoder, Limits};
use psao_gpu::{GpuMirror, GpuReconstruct};
use psao_scene::*;

mod support;
use support::arg;

fn main() {
    let density: f32 = arg("--density", 2048.0);
    let reps: u32 = arg("--reps", 3).max(1);
    let ctx = support::open_context();
    let scene = default_scene();
    let mut p = Pipeline::new(
        scene.clone(),
        PipelineConfig {
            density,
            ao: AoParams {
                rays: 16,
                ..AoParams::default()
            },
            ..PipelineConfig::default()
        },
    )
    .expect("the default scene builds");
    let mut client = Decoder::new(Limits::default());
    client
        .receive(&p.keyframe().expect("keyframe").bytes)
        .expect("decodes");
    let camera = scene.camera.as_ref().expect("camera path").at(0.0);
    let view = View::new(camera, 1920, 1080).expect("view");
    let g = PosedScene::new(&scene, 0.0).expect("poses").gbuffer(&view);
    let t = Instant::now();
    let gm = GpuMirror::new(&ctx, client.mirror()).expect("mirror upload");
    let upload_ms = t.elapsed().as_secs_f64() * 1e3;
    let pass = GpuReconstruct::new(&ctx).expect("pass");
    let _ = pass.run(&ctx, &gm, &g); // warm up: the driver compiles the shader
    let mut gpu = Vec::new();
    let gpu_ms = support::best_ms(reps, || gpu = pass.run(&ctx, &gm, &g).expect("gpu pass"));
    let mut cpu = Vec::new();
    let cpu_ms = support::best_ms(reps, || {
        cpu = psao_image(client.mirror(), &g).expect("cpu").ao
    });
    let sao_ms = support::best_ms(reps, || {
        let _ = sao(&g.depth, &view, &SaoParams::default()).expect("sao");
    });
    let same = cpu
        .iter()
        .zip(&gpu)
        .filter(|(a, b)| (*a - *b).abs() <= 1.0 / 255.0)
        .count() as f64
        / cpu.len() as f64;
    println!(
        "default scene at 1920x1080, {} points (density {density}), {:.0}% of pixels covered; GPU: {}",
        (0..p.instance_count())
            .filter_map(|i| p.points(i).map(|s| s.len()))
            .sum::<usize>(),
        100.0 * g.covered() as f64 / g.pixels() as f64,
        ctx.describe()
    );
    println!(
        "PSAO reconstruction: GPU pass {gpu_ms:.1} ms (G-buffer upload and readback included), CPU {cpu_ms:.1} ms ({} threads); CPU SAO {sao_ms:.1} ms",
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "ratios: GPU reconstruction / CPU SAO {:.2}x, CPU reconstruction / CPU SAO {:.2}x, GPU / CPU reconstruction {:.2}x; mirror upload {upload_ms:.1} ms ({} bytes); {:.3}% of pixels within 1/255 of the CPU",
        gpu_ms / sao_ms,
        cpu_ms / sao_ms,
        gpu_ms / cpu_ms,
        gm.last_upload_bytes(),
        same * 100.0
    );
}
