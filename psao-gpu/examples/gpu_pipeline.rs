//! Where a server tick goes on each backend: the default scene's pipeline
//! stepped at 60 Hz on the CPU backend and on the GPU backend (wgpu ray
//! queries), same scene, same settings, same run; mean milliseconds per
//! tick of each stage of `psao_scene::FrameReport`. On the GPU backend the
//! trace stage holds placing the acceleration structures (skinned BLAS
//! rebuild, TLAS), the AO pass, the comparison with what clients hold and
//! reading back the changed points.
//!
//! `cargo run --release -p psao-gpu --example gpu_pipeline [-- --density 128 --frames 120]`

use psao_gpu::GpuBackend;
use psao_scene::*;

mod support;
use support::arg;

fn main() {
    let density: f32 = arg("--density", 128.0);
    let frames: u32 = arg("--frames", 120).max(1);
    let ctx_name = support::open_context().describe();
    let scene = default_scene();
    let config = PipelineConfig {
        density,
        ..PipelineConfig::default()
    };
    println!("default scene, density {density}, {frames} ticks at 60 Hz; GPU: {ctx_name}");
    println!(
        "| backend | traced / tick | animate ms | select ms | BVH ms | trace ms | encode ms | total ms |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut totals = Vec::new();
    for gpu in [false, true] {
        let mut p = if gpu {
            let backend = GpuBackend::new(&scene).expect("GPU backend");
            Pipeline::with_backend(scene.clone(), config.clone(), Box::new(backend))
        } else {
            Pipeline::new(scene.clone(), config.clone())
        }
        .expect("the default scene builds");
        p.keyframe().expect("keyframe");
        // One tick to warm up (shader compilation on the GPU).
        p.step(1.0 / 60.0).expect("tick");
        let mut sum = FrameReport::default();
        for _ in 0..frames {
            let (_, report) = p.step(1.0 / 60.0).expect("tick");
            sum.accumulate(&report);
        }
        let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3 / frames as f64;
        println!(
            "| {} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            if gpu { "GPU" } else { "CPU" },
            sum.traced as f64 / frames as f64,
            ms(sum.t_animate),
            ms(sum.t_select),
            ms(sum.t_bvh),
            ms(sum.t_trace),
            ms(sum.t_encode),
            ms(sum.total_time())
        );
        totals.push(ms(sum.total_time()));
    }
    println!("GPU / CPU per tick: {:.2}x", totals[1] / totals[0]);
}
