//! What the psao-gpu examples share: argument reading, the device, a
//! pipeline and timing (pipelines and world points come from the test kit,
//! `psao_tests::scenes`).

use std::time::Instant;

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
    psao_tests::scenes::pipeline(scene, density, PipelineConfig::default().ao.rays)
}

/// The device with ray queries, or exit with status 2 and the error (what
/// to install).
#[allow(dead_code)]
pub fn open_context() -> GpuContext {
    exit_on_error(GpuContext::new())
}

/// A device for the client half and SAO only (ray queries or not), or exit
/// with status 2 and the error.
#[allow(dead_code)]
pub fn open_client_context() -> GpuContext {
    exit_on_error(GpuContext::new_client())
}

fn exit_on_error(c: Result<GpuContext, psao_gpu::GpuError>) -> GpuContext {
    c.unwrap_or_else(|e| {
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
