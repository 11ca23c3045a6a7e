//! What the psao-gpu examples (and `tests/gpu_vs_cpu.rs`) share:
//! argument reading, pipelines and the server points of a pipeline.

use std::time::Instant;

use glam::Vec3;
use psao_gpu::GpuContext;
use psao_scene::{Pipeline, PipelineConfig, Scene};

/// The value after `name` on the command line, or `default`.
#[allow(dead_code)]
pub fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A pipeline over `scene` (the default scene in the examples) with
/// `density` kept points per m^2, otherwise the defaults.
#[allow(dead_code)]
pub fn default_pipeline(scene: &Scene, density: f32) -> Pipeline {
    pipeline_with(scene, density, PipelineConfig::default().ao.rays)
}

/// [`default_pipeline`] with `rays` AO rays per point.
#[allow(dead_code)]
pub fn pipeline_with(scene: &Scene, density: f32, rays: u32) -> Pipeline {
    Pipeline::new(
        scene.clone(),
        PipelineConfig::with_density_and_rays(density, rays),
    )
    .expect("the scene builds")
}

/// Every point of the pipeline's instances in world space, with ids.
#[allow(dead_code)]
pub fn world_points(p: &Pipeline) -> (Vec<u32>, Vec<Vec3>, Vec<Vec3>) {
    let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..p.instance_count() {
        let (Some((pos, n)), Some(t)) = (p.current_points(i), p.transform(i)) else {
            continue;
        };
        let nm = t.matrix3.inverse().transpose();
        for k in 0..pos.len() {
            ids.push(ids.len() as u32);
            pts.push(t.transform_point3(pos[k]));
            nrm.push((nm * n[k]).normalize());
        }
    }
    (ids, pts, nrm)
}

/// The device, or exit with status 2 and the error (what to install).
#[allow(dead_code)]
pub fn open_context() -> GpuContext {
    GpuContext::new().unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(2)
    })
}

/// The fastest of `reps` runs of `f`, in milliseconds.
#[allow(dead_code)]
pub fn best_ms(reps: u32, mut f: impl FnMut()) -> f64 {
    (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::MAX, f64::min)
}
