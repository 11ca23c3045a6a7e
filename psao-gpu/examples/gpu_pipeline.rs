//! Where a server tick goes on each backend: the default scene's pipeline
//! stepped at 60 Hz on the CPU backend and on the GPU backend (wgpu ray
//! queries), same scene, same settings, same run; mean milliseconds per
//! tick of each stage of `psao_scene::FrameReport`, for three ways of
//! keeping ray scores: none (every point traced traces all its rays: the
//! GPU backend's only way before it cast single rays), ray reuse (a
//! static point re-casts only the rays motion reached), and ray reuse
//! with early decisions. On the GPU backend the trace stage holds placing
//! the acceleration structures (skinned BLAS rebuild, TLAS), the AO or
//! single-ray passes and reading back what they give. Each row prints a
//! digest of its frames: the same scores kept on both backends send the
//! same frames.
//!
//! `cargo run --release -p psao-gpu --example gpu_pipeline [-- --density 128 --frames 120 --ray-budget 0]`
//! (`--ray-budget 0`: none)

use std::hash::{DefaultHasher, Hasher};

use psao_gpu::GpuBackend;
use psao_scene::*;

mod support;
use support::arg;

fn main() {
    let density: f32 = arg("--density", 128.0);
    let frames: u32 = arg("--frames", 120).max(1);
    let budget = match arg("--ray-budget", 0u64) {
        0 => RayBudget::Unlimited,
        n => RayBudget::Rays(n),
    };
    let ctx_name = support::open_context().describe();
    let scene = default_scene();
    println!(
        "default scene, density {density}, {frames} ticks at 60 Hz, budget {budget:?}; GPU: {ctx_name}"
    );
    println!(
        "| scores kept | backend | traced / tick | rays / tick | early stops / tick | animate ms | select ms | BVH ms | trace ms (plan, choose, cast) | encode ms | total ms | frames digest |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let early = Some(EarlyDecisions::default());
    let mut totals = Vec::new();
    for (scores, ray_reuse, early) in [
        ("none", false, None),
        ("ray reuse", true, None),
        ("ray reuse, early decisions", true, early),
    ] {
        let config = PipelineConfig {
            density,
            budget,
            ray_reuse,
            early,
            ..PipelineConfig::default()
        };
        let mut row = Vec::new();
        for gpu in [false, true] {
            let mut p = if gpu {
                let backend = GpuBackend::new(&scene).expect("GPU backend");
                Pipeline::with_backend(scene.clone(), config.clone(), Box::new(backend))
            } else {
                Pipeline::new(scene.clone(), config.clone())
            }
            .expect("the default scene builds");
            let mut digest = DefaultHasher::new();
            digest.write(&p.keyframe().expect("keyframe").bytes);
            // One tick to warm up (shader compilation on the GPU).
            let (frame, _) = p.step(1.0 / 60.0).expect("tick");
            digest.write(&frame.map(|f| f.bytes).unwrap_or_default());
            let mut sum = FrameReport::default();
            for _ in 0..frames {
                let (frame, report) = p.step(1.0 / 60.0).expect("tick");
                digest.write(&frame.map(|f| f.bytes).unwrap_or_default());
                sum.accumulate(&report);
            }
            let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3 / frames as f64;
            let per = |n: u64| n as f64 / frames as f64;
            let digest = digest.finish();
            println!(
                "| {scores} | {} | {:.0} | {:.0} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} ({:.2}, {:.2}, {:.2}) | {:.2} | {:.2} | {digest:016x} |",
                if gpu { "GPU" } else { "CPU" },
                per(sum.traced),
                per(sum.rays),
                per(sum.early),
                ms(sum.t_animate),
                ms(sum.t_select),
                ms(sum.t_bvh),
                ms(sum.t_trace),
                ms(sum.trace_phases.plan),
                ms(sum.trace_phases.choose),
                ms(sum.trace_phases.cast),
                ms(sum.t_encode),
                ms(sum.total_time())
            );
            row.push((ms(sum.total_time()), digest));
        }
        totals.push((scores, row));
    }
    for (scores, row) in &totals {
        println!(
            "scores kept: {scores}: GPU / CPU per tick {:.2}x; frames {}",
            row[1].0 / row[0].0,
            if row[0].1 == row[1].1 {
                "the same on both"
            } else {
                "differ"
            }
        );
    }
    let gpu = |k: usize| totals[k].1[1].0;
    println!(
        "GPU per tick against no scores kept: ray reuse {:.2}x, with early decisions {:.2}x",
        gpu(1) / gpu(0),
        gpu(2) / gpu(0)
    );
}
