//! Where a server tick goes on each backend: the default scene's pipeline
//! stepped at 60 Hz on the CPU backend and on the GPU backend (wgpu ray
//! queries), same scene, same settings, same run; mean milliseconds per
//! tick of each stage of `psao_scene::FrameReport`, for three ways of
//! keeping ray scores: none (every point within reach of motion traces
//! all its rays), ray reuse (a static point re-casts only the rays motion
//! reached), and ray reuse with early decisions; the GPU backend tracing
//! whole points (its default: no scores kept, every ray of a point it
//! traces) and casting single rays (`GpuBackend::with_single_rays`: the
//! CPU's rules). On the GPU backend the trace stage holds placing the
//! acceleration structures (skinned BLAS rebuild, TLAS), the AO or
//! single-ray passes and reading back what they give. Each row prints a
//! digest of its frames: the same scores kept on both backends send the
//! same frames wherever the backends' rays score alike.
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
    // Per configuration, per backend: (ms per tick, frames digest).
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
        // The CPU; the GPU tracing whole points; the GPU casting single
        // rays (the same as whole points where no scores are kept).
        let backends: &[(&str, Option<bool>)] = if ray_reuse {
            &[
                ("CPU", None),
                ("GPU, whole points", Some(false)),
                ("GPU, single rays", Some(true)),
            ]
        } else {
            &[("CPU", None), ("GPU, whole points", Some(false))]
        };
        for &(name, gpu) in backends {
            let mut p = match gpu {
                Some(single) => {
                    let backend = GpuBackend::new(&scene)
                        .expect("GPU backend")
                        .with_single_rays(single);
                    Pipeline::with_backend(scene.clone(), config.clone(), Box::new(backend))
                }
                None => Pipeline::new(scene.clone(), config.clone()),
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
                "| {scores} | {name} | {:.0} | {:.0} | {:.0} | {:.2} | {:.2} | {:.2} | {:.2} ({:.2}, {:.2}, {:.2}) | {:.2} | {:.2} | {digest:016x} |",
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
            row.push((name, ms(sum.total_time()), digest));
        }
        totals.push((scores, row));
    }
    for (scores, row) in &totals {
        let (_, cpu, cpu_digest) = row[0];
        for &(name, ms, digest) in &row[1..] {
            println!(
                "scores kept: {scores}: {name} / CPU per tick {:.2}x; frames {}",
                ms / cpu,
                if digest == cpu_digest {
                    "the same as the CPU's"
                } else {
                    "differ from the CPU's"
                }
            );
        }
    }
}
