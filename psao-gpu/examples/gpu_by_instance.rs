//! Where the GPU backend is slow: the points of each instance of the
//! default scene traced alone, 64 closest-hit rays each, on the GPU (wgpu
//! ray queries) and on the CPU (obvhs), same rays, same run, best of `--reps` (5).
//! Also times posing the GPU scene (skinned BLAS rebuild and TLAS).
//!
//! `cargo run --release -p psao-gpu --example gpu_by_instance [-- --density 256 --most 1200 --reps 5]`

use psao_eval::*;
use psao_gpu::{GpuAo, GpuScene};
use psao_scene::*;

mod support;

use support::arg;

/// Runs per timing (`--reps`, default 5); the fastest counts.
fn reps() -> u32 {
    arg("--reps", 5)
}

fn main() {
    let density: f32 = arg("--density", 256.0);
    let most: usize = arg("--most", 1200);
    let ctx = support::open_context();
    let scene = default_scene();
    let p = support::default_pipeline(&scene, density);
    let mut gpu_scene = GpuScene::new(&ctx, &scene).expect("GPU scene");
    let ao = GpuAo::new(&ctx).expect("AO pass");
    let cpu = PosedScene::new(&scene, 0.0).expect("poses").tracer();
    let params = AoParams {
        rays: 64,
        ..AoParams::default()
    };
    println!("default scene, density {density}, GPU: {}", ctx.describe());
    let pose_ms = support::best_ms(reps(), || {
        gpu_scene.pose(&ctx, &scene, 0.0).expect("poses");
    });
    println!("posing the GPU scene (skinned BLAS, TLAS): {pose_ms:.2} ms");
    println!("| instance | kind | points | GPU ms | CPU ms | GPU / CPU |");
    println!("|---|---|---|---|---|---|");
    let dynamic = scene.dynamic_instances();
    for (i, &moves) in dynamic.iter().enumerate() {
        let (Some((pos, n)), Some(t)) = (p.current_points(i), p.transform(i)) else {
            continue;
        };
        let take = pos.len().min(most);
        if take == 0 {
            continue;
        }
        let nm = t.matrix3.inverse().transpose();
        let pts: Vec<_> = pos[..take].iter().map(|q| t.transform_point3(*q)).collect();
        let nrm: Vec<_> = n[..take].iter().map(|q| (nm * *q).normalize()).collect();
        let ids: Vec<u32> = (0..take as u32).collect();
        // Warm up (the driver compiles the shader on first use).
        let _ = ao.trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params);
        let g = support::best_ms(reps(), || {
            ao.trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params)
                .expect("gpu");
        });
        let c = support::best_ms(reps(), || {
            cpu.trace_ids(&ids, &pts, &nrm, &params).expect("cpu");
        });
        let kind = if scene.instances[i].skin.is_some() {
            "skinned"
        } else if moves {
            "moving"
        } else {
            "static"
        };
        println!(
            "| {i} | {kind} | {take} | {g:.1} | {c:.1} | {:.2}x |",
            g / c
        );
    }
}
