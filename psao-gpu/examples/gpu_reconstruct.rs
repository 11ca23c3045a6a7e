//! Client reconstruction at 1920x1080 on the default scene against the SAO
//! baseline on the same device, same G-buffer, same run: the WGSL passes on
//! the GPU (wgpu; lavapipe runs them on this machine's CPU cores), and
//! psao-codec's reconstruction and psao-scene's SAO on the CPU. GPU times
//! are given for the passes alone (inputs on the device, as in a renderer)
//! and with uploading the inputs and reading the image back; the upload of
//! the mirror is timed apart. Needs no ray queries (any Vulkan device).
//!
//! `cargo run --release -p psao-gpu --example gpu_reconstruct [-- --density 2048 --reps 3]`

use std::time::Instant;

use psao_codec::{Decoder, Limits};
use psao_eval::*;
use psao_gpu::{GpuMirror, GpuReconstruct, GpuSao, PassTimes};
use psao_scene::*;

mod support;
use support::arg;

fn main() {
    let density: f32 = arg("--density", 2048.0);
    let reps: u32 = arg("--reps", 3).max(1);
    let ctx = support::open_client_context();
    let scene = default_scene();
    let mut p = psao_tests::scenes::pipeline(&scene, density, 16);
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
    let gpu_sao = GpuSao::new(&ctx).expect("sao passes");
    let params = SaoParams::default();
    // Warm up: the driver compiles the shaders.
    let _ = pass.run(&ctx, &gm, &g);
    let _ = gpu_sao.run(&ctx, &g.depth, &view, &params);
    // Best of `reps` for each, interleaved so that both see the same
    // machine.
    let (mut gpu, mut sao_img) = (Vec::new(), Vec::new());
    let (mut psao_t, mut sao_t) = (PassTimes::default(), PassTimes::default());
    for rep in 0..reps {
        let (img, t) = pass.run_timed(&ctx, &gm, &g).expect("gpu pass");
        gpu = img;
        psao_t = best(rep, psao_t, t);
        let (img, t) = gpu_sao
            .run_timed(&ctx, &g.depth, &view, &params)
            .expect("gpu sao");
        sao_img = img;
        sao_t = best(rep, sao_t, t);
    }
    let mut cpu = Vec::new();
    let cpu_ms = support::best_ms(reps, || {
        cpu = psao_image(client.mirror(), &g).expect("cpu").ao
    });
    let mut cpu_sao = Vec::new();
    let sao_ms = support::best_ms(reps, || {
        cpu_sao = sao(&g.depth, &view, &params).expect("sao");
    });
    let within = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .filter(|(x, y)| (*x - *y).abs() <= 1.0 / 255.0)
            .count() as f64
            / a.len().max(1) as f64
            * 100.0
    };
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    println!(
        "default scene at 1920x1080, {} points (density {density}), {:.0}% of pixels covered; GPU: {}; best of {reps}",
        (0..p.instance_count())
            .filter_map(|i| p.points(i).map(|s| s.len()))
            .sum::<usize>(),
        100.0 * g.covered() as f64 / g.pixels() as f64,
        ctx.describe()
    );
    println!(
        "GPU passes alone (inputs on the device): PSAO reconstruction {:.1} ms, SAO {:.1} ms: ratio {:.2}x",
        ms(psao_t.passes),
        ms(sao_t.passes),
        ms(psao_t.passes) / ms(sao_t.passes)
    );
    println!(
        "GPU with uploads and readback: PSAO reconstruction {:.1} ms, SAO {:.1} ms: ratio {:.2}x",
        ms(psao_t.total),
        ms(sao_t.total),
        ms(psao_t.total) / ms(sao_t.total)
    );
    println!(
        "CPU ({} threads): PSAO reconstruction {cpu_ms:.1} ms, SAO {sao_ms:.1} ms: ratio {:.2}x; GPU pass / CPU: reconstruction {:.2}x, SAO {:.2}x",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        cpu_ms / sao_ms,
        ms(psao_t.passes) / cpu_ms,
        ms(sao_t.passes) / sao_ms
    );
    println!(
        "agreement: reconstruction {:.3}% and SAO {:.3}% of pixels within 1/255 of the CPU; mirror upload {upload_ms:.1} ms ({} bytes)",
        within(&cpu, &gpu),
        within(&cpu_sao, &sao_img),
        gm.last_upload_bytes(),
    );
}

/// The faster of two timings by pass time (the first rep's own).
fn best(rep: u32, a: PassTimes, b: PassTimes) -> PassTimes {
    if rep == 0 || b.passes < a.passes {
        b
    } else {
        a
    }
}
