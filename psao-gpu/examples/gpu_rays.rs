//! Rays per second of the GPU backend (wgpu ray queries) against the CPU
//! backend (obvhs) on the same points of the default scene (rigid,
//! skinned and alpha-masked instances), same rays, same run; both
//! estimators. Prints the device,
//! the rates, their ratio and how far the results differ.
//!
//! `cargo run --release -p psao-gpu --example gpu_rays [-- --density 64 --rays 64 --reps 3 --radius 0.6]`

use std::time::Instant;

use psao_eval::*;
use psao_gpu::{GpuAo, GpuScene};
use psao_scene::*;

mod support;
use support::arg;

fn main() {
    let density: f32 = arg("--density", 64.0);
    let rays: u32 = arg("--rays", 64);
    let reps: u32 = arg("--reps", 3).max(1);
    let radius: f32 = arg("--radius", AoParams::default().radius);
    let ctx = support::open_context();
    let scene = default_scene();
    let p = support::default_pipeline(&scene, density);
    let (ids, pts, nrm) = psao_tests::scenes::world_points(&p);
    let cpu = PosedScene::new(&scene, 0.0).expect("poses").tracer();
    let gpu_scene = GpuScene::new(&ctx, &scene).expect("GPU scene");
    let ao = GpuAo::new(&ctx).expect("AO pass");
    println!(
        "default scene: {} points x {rays} rays, {} triangles; CPU: {} threads (obvhs); GPU: {}",
        pts.len(),
        gpu_scene.triangles(),
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        ctx.describe()
    );
    for estimator in [Estimator::ClosestHit, Estimator::LaineKarras] {
        let params = AoParams {
            rays,
            estimator,
            radius,
            ..AoParams::default()
        };
        // Warm up (the first dispatch compiles the shader in the driver).
        let _ = ao.trace_ids(
            &ctx,
            &gpu_scene,
            &ids[..64.min(ids.len())],
            &pts[..64.min(pts.len())],
            &nrm[..64.min(nrm.len())],
            &params,
        );
        let (mut t_cpu, mut t_gpu, mut t_single) = (f64::MAX, f64::MAX, f64::MAX);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        // The same rays as single-ray jobs (`GpuAo::cast_rays`, as the
        // pipeline casts kept-score rays), every ray of every point.
        let jobs: Vec<RayJob> = (0..pts.len() as u32)
            .flat_map(|point| (0..rays).map(move |ray| RayJob { point, ray }))
            .collect();
        for _ in 0..reps {
            let t = Instant::now();
            a = cpu.trace_ids(&ids, &pts, &nrm, &params).expect("cpu").ao;
            t_cpu = t_cpu.min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            b = ao
                .trace_ids(&ctx, &gpu_scene, &ids, &pts, &nrm, &params)
                .expect("gpu")
                .ao;
            t_gpu = t_gpu.min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            let single = ao
                .cast_rays(&ctx, &gpu_scene, &ids, &pts, &nrm, &jobs, &params)
                .expect("gpu single rays");
            t_single = t_single.min(t.elapsed().as_secs_f64());
            assert_eq!(single.len(), jobs.len());
        }
        let n_rays = (pts.len() as u64 * rays as u64) as f64;
        let within = a
            .iter()
            .zip(&b)
            .filter(|(x, y)| (*x - *y).abs() <= 1.0 / 255.0)
            .count() as f64
            / a.len().max(1) as f64;
        println!(
            "{estimator:?}: CPU {:.2} Mrays/s ({:.3} s), GPU {:.2} Mrays/s ({:.3} s, upload and readback included); GPU/CPU {:.2}x; {:.3}% of points within 1/255",
            n_rays / t_cpu / 1e6,
            t_cpu,
            n_rays / t_gpu / 1e6,
            t_gpu,
            t_cpu / t_gpu,
            within * 100.0
        );
        println!(
            "{estimator:?}: GPU single-ray jobs {:.2} Mrays/s ({:.3} s); against the AO pass {:.2}x the time",
            n_rays / t_single / 1e6,
            t_single,
            t_single / t_gpu
        );
    }
}
