//! The SAO baseline on the GPU against psao-eval's CPU passes, on a device
//! without ray queries (SAO needs none). Without a Vulkan adapter the
//! tests say so and pass, unless `PSAO_REQUIRE_GPU` is set (CI sets it).

mod common;

use common::{agreement, client_context};
use glam::Vec3;
use psao_eval::*;
use psao_gpu::*;
use psao_scene::*;

#[test]
fn gpu_sao_matches_the_cpu_baseline() {
    let Some(ctx) = client_context() else { return };
    let scene = default_scene();
    let cam = scene.camera.as_ref().unwrap().at(1.0);
    // Odd sides: the pyramid's clamped edges and the quads' lone row and
    // column.
    let view = View::new(cam, 161, 97).unwrap();
    let g = PosedScene::new(&scene, 1.0).unwrap().gbuffer(&view);
    let mut depth = g.depth.clone();
    // Sky in all its forms, as the CPU takes it.
    for (i, d) in depth.iter_mut().enumerate() {
        match i % 211 {
            0 => *d = f32::NAN,
            1 => *d = -1.0,
            2 => *d = 0.0,
            _ => {}
        }
    }
    let sao_gpu = GpuSao::new(&ctx).unwrap();
    for params in [
        SaoParams::default(),
        SaoParams {
            blur_radius: 0,
            ..SaoParams::default()
        },
        SaoParams {
            mip_levels: 0,
            contrast: 2.0,
            ..SaoParams::default()
        },
    ] {
        let cpu = sao(&depth, &view, &params).unwrap();
        let (gpu, times) = sao_gpu.run_timed(&ctx, &depth, &view, &params).unwrap();
        assert!(times.passes <= times.total);
        let (share, worst) = agreement(&cpu, &gpu);
        let mean = cpu
            .iter()
            .zip(&gpu)
            .map(|(a, b)| (a - b).abs())
            .sum::<f32>()
            / cpu.len() as f32;
        eprintln!(
            "blur {} mips {}: {:.3}% within 1/255, mean {mean:e}, worst {worst}",
            params.blur_radius,
            params.mip_levels,
            share * 100.0
        );
        // Equal here but for pow's last bits with a contrast; a device
        // whose sin and cos differ in their last bits may move a tap to
        // the next pixel now and then.
        assert!(share >= 0.999, "{:.3}% within 1/255", share * 100.0);
        assert!(mean < 1e-3, "mean difference {mean}");
        for (i, (&d, &a)) in depth.iter().zip(&gpu).enumerate() {
            if !(d.is_finite() && d > 0.0) {
                assert_eq!(a, 1.0, "sky pixel {i}");
            }
            assert!((0.0..=1.0).contains(&a), "pixel {i}: {a}");
        }
        // And it is not open everywhere: the scene has creases.
        let dark = gpu.iter().filter(|&&a| a < 0.9).count();
        eprintln!("{dark} pixels below 0.9");
        assert!(dark > cpu.len() / 200, "{dark} pixels below 0.9");
    }
    // Errors as on the CPU.
    let bad = SaoParams {
        samples: 0,
        ..SaoParams::default()
    };
    assert!(matches!(
        sao_gpu.run(&ctx, &depth, &view, &bad),
        Err(GpuError::Scene(SceneError::Parameter { .. }))
    ));
    assert!(
        sao_gpu
            .run(&ctx, &depth[1..], &view, &SaoParams::default())
            .is_err()
    );
}

#[test]
fn gpu_sao_handles_tiny_images_sky_and_extreme_constants() {
    let Some(ctx) = client_context() else { return };
    let sao_gpu = GpuSao::new(&ctx).unwrap();
    let cam = Camera {
        eye: Vec3::new(0.0, 1.0, 5.0),
        target: Vec3::ZERO,
        fov_y: 1.0,
    };
    let extreme = SaoParams {
        radius: 1e29,
        intensity: 1e6,
        epsilon: 1e-30,
        contrast: 100.0,
        blur_radius: 64,
        blur_stride: 64,
        mip_levels: 15,
        log_q: 0,
        ..SaoParams::default()
    };
    for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 2), (3, 7)] {
        let view = View::new(cam, w, h).unwrap();
        let n = view.pixels();
        let specials = [
            f32::NAN,
            f32::INFINITY,
            -1.0,
            0.0,
            f32::MAX,
            1e-40,
            2.0,
            3.5,
        ];
        let depth: Vec<f32> = (0..n).map(|i| specials[i % specials.len()]).collect();
        for params in [SaoParams::default(), extreme] {
            let cpu = sao(&depth, &view, &params).unwrap();
            let gpu = sao_gpu.run(&ctx, &depth, &view, &params).unwrap();
            assert_eq!(gpu.len(), n);
            assert!(
                gpu.iter().all(|a| (0.0..=1.0).contains(a)),
                "{w}x{h}: {gpu:?}"
            );
            let (share, worst) = agreement(&cpu, &gpu);
            assert_eq!(
                share, 1.0,
                "{w}x{h}: worst {worst}, {cpu:?} against {gpu:?}"
            );
        }
        let sky = sao_gpu
            .run(&ctx, &vec![f32::INFINITY; n], &view, &SaoParams::default())
            .unwrap();
        assert!(sky.iter().all(|&a| a == 1.0));
    }
}
