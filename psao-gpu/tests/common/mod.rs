//! What the GPU tests share: the devices (skipped without a driver unless
//! `PSAO_REQUIRE_GPU` is set), scenes, and the comparison of two images.
#![allow(dead_code)]

use psao_eval::*;
use psao_gpu::*;
use psao_scene::*;
use psao_tests::scenes::pipeline;

/// A device with ray queries, for the server half.
pub fn context() -> Option<GpuContext> {
    skip_or_panic(GpuContext::new())
}

/// A device the way a renderer hands one in: requested by the test itself
/// with no feature ([`GpuContext::CLIENT_FEATURES`]) and exactly
/// [`GpuContext::client_limits`], so no ray queries and nothing beyond
/// WebGPU's downlevel limits, then wrapped with
/// [`GpuContext::from_device`].
pub fn client_context() -> Option<GpuContext> {
    skip_or_panic(
        renderer_device(GpuContext::client_limits())
            .and_then(|(device, queue)| GpuContext::from_device(device, queue)),
    )
}

/// A device and queue requested with no feature and exactly `limits`, as
/// a renderer would request its own.
pub fn renderer_device(limits: wgpu::Limits) -> Result<(wgpu::Device, wgpu::Queue), GpuError> {
    pollster::block_on(async {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::VULKAN,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        });
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions::default())
            .await
            .map_err(|e| GpuError::NoAdapter {
                details: e.to_string(),
            })?;
        adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("a renderer's device"),
                required_features: GpuContext::CLIENT_FEATURES,
                required_limits: limits,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::Device(e.to_string()))
    })
}

fn skip_or_panic(c: Result<GpuContext, GpuError>) -> Option<GpuContext> {
    match c {
        Ok(c) => Some(c),
        Err(e) if std::env::var_os("PSAO_REQUIRE_GPU").is_none() => {
            eprintln!("skipped (set PSAO_REQUIRE_GPU to fail instead): {e}");
            None
        }
        Err(e) => panic!("PSAO_REQUIRE_GPU is set: {e}"),
    }
}

/// The default scene with its trellis made solid (alpha masks are not on
/// the GPU yet).
pub fn solid_default_scene() -> Scene {
    let mut s = default_scene();
    for m in &mut s.meshes {
        m.alpha = None;
    }
    s
}

/// Share of values that agree within 1/255, and the largest difference.
pub fn agreement(a: &[f32], b: &[f32]) -> (f64, f32) {
    assert_eq!(a.len(), b.len());
    let close = a
        .iter()
        .zip(b)
        .filter(|(x, y)| (*x - *y).abs() <= 1.0 / 255.0)
        .count();
    let worst = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max);
    (close as f64 / a.len().max(1) as f64, worst)
}

/// The default scene's mirror after a keyframe, its pipeline and a
/// G-buffer at time 0.
pub fn client_side(density: f32) -> (Pipeline, psao_codec::Decoder, Scene) {
    let scene = default_scene();
    let mut p = pipeline(&scene, density, 16);
    let mut c = psao_codec::Decoder::new(psao_codec::Limits::default());
    c.receive(&p.keyframe().unwrap().bytes).unwrap();
    (p, c, scene)
}

pub fn gbuffer_at(scene: &Scene, t: f32) -> GBuffer {
    let cam = scene.camera.as_ref().unwrap().at(t);
    let view = View::new(cam, 96, 54).unwrap();
    PosedScene::new(scene, t).unwrap().gbuffer(&view)
}
