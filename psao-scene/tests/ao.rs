//! AO against analytic cases, for both estimators.

use glam::{Affine3A, Vec3};
use psao_scene::*;

fn params(estimator: Estimator, rays: u32) -> AoParams {
    AoParams {
        radius: 0.6,
        rays,
        bias: 1e-4,
        estimator,
        seed: 7,
    }
}

const BOTH: [Estimator; 2] = [Estimator::ClosestHit, Estimator::LaineKarras];

#[test]
fn open_plane_is_unoccluded() {
    let mut scene = Scene::default();
    scene.add(
        Mesh::quad(
            Vec3::new(-50.0, -50.0, 0.0),
            Vec3::X * 100.0,
            Vec3::Y * 100.0,
        ),
        Affine3A::IDENTITY,
    );
    let tracer = AoTracer::new(&scene.world_triangles().unwrap());
    let pts: Vec<Vec3> = (0..50)
        .map(|i| Vec3::new(i as f32 * 0.3 - 7.0, i as f32 * 0.1, 0.0))
        .collect();
    for e in BOTH {
        let r = tracer
            .trace(&pts, &vec![Vec3::Z; pts.len()], &params(e, 64))
            .unwrap();
        assert!(r.ao.iter().all(|&a| a == 1.0), "{e:?}: {:?}", r.ao);
        assert_eq!(r.rays, 50 * 64);
    }
}

#[test]
fn inside_a_small_closed_box_ao_is_bounded_by_its_size() {
    let s = 0.1;
    let mut scene = Scene::default();
    scene.add(Mesh::cuboid(Vec3::ZERO, Vec3::splat(s)), Affine3A::IDENTITY);
    let tracer = AoTracer::new(&scene.world_triangles().unwrap());
    let pts: Vec<Vec3> = (0..20)
        .map(|i| Vec3::splat(0.02 + i as f32 * 0.003))
        .collect();
    let nrm: Vec<Vec3> = (0..20)
        .map(|i| Vec3::new(i as f32 - 10.0, 3.0, 1.0).normalize())
        .collect();
    // Every ray hits within the diagonal, so min(t, R)/R <= s sqrt(3) / R.
    let bound = s * 3f32.sqrt() / 0.6;
    let closest = tracer
        .trace(&pts, &nrm, &params(Estimator::ClosestHit, 128))
        .unwrap();
    assert!(closest.ao.iter().all(|&a| a <= bound), "{:?}", closest.ao);
    let lk = tracer
        .trace(&pts, &nrm, &params(Estimator::LaineKarras, 128))
        .unwrap();
    let mean = lk.ao.iter().sum::<f32>() / lk.ao.len() as f32;
    assert!(mean <= bound + 0.03, "mean {mean} > {bound}");
    assert!(lk.ao.iter().all(|&a| a < 1.0));
}

/// E[min(t, R) / R] for a point with normal +Z and an infinite wall x = d,
/// by midpoint quadrature over the cosine-distributed directions.
fn wall_expectation(d: f32, r: f32) -> f64 {
    let n = 1000;
    let mut sum = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            let r1 = (i as f64 + 0.5) / n as f64;
            let r2 = (j as f64 + 0.5) / n as f64;
            let wx = r1.sqrt() * (std::f64::consts::TAU * r2).cos();
            let t = if wx > 0.0 {
                d as f64 / wx
            } else {
                f64::INFINITY
            };
            sum += t.min(r as f64) / r as f64;
        }
    }
    sum / (n * n) as f64
}

#[test]
fn wall_at_distance_matches_integration() {
    for d in [0.1f32, 0.3] {
        let mut scene = Scene::default();
        scene.add(
            Mesh::quad(
                Vec3::new(d, -1000.0, -1000.0),
                Vec3::Y * 2000.0,
                Vec3::Z * 2000.0,
            ),
            Affine3A::IDENTITY,
        );
        let tracer = AoTracer::new(&scene.world_triangles().unwrap());
        let pts: Vec<Vec3> = (0..32)
            .map(|i| Vec3::new(0.0, i as f32 * 0.25, 0.0))
            .collect();
        let nrm = vec![Vec3::Z; pts.len()];
        let expect = wall_expectation(d, 0.6);
        for e in BOTH {
            let r = tracer.trace(&pts, &nrm, &params(e, 2048)).unwrap();
            let mean = r.ao.iter().map(|&a| a as f64).sum::<f64>() / r.ao.len() as f64;
            // 65,536 rays, per-ray standard deviation <= 0.5: 5 sigma ~ 0.01.
            assert!(
                (mean - expect).abs() < 0.01,
                "d {d} {e:?}: {mean} vs {expect}"
            );
        }
        assert!(expect > 0.5 && expect < 1.0);
    }
}

#[test]
fn tracing_is_deterministic_and_seeded() {
    let mut scene = Scene::default();
    scene.add(
        Mesh::cuboid(Vec3::new(-1.0, -1.0, 0.2), Vec3::new(1.0, 1.0, 0.5)),
        Affine3A::IDENTITY,
    );
    let tracer = AoTracer::new(&scene.world_triangles().unwrap());
    let pts: Vec<Vec3> = (0..64)
        .map(|i| Vec3::new(i as f32 * 0.05 - 1.5, 0.0, 0.0))
        .collect();
    let nrm = vec![Vec3::Z; pts.len()];
    for e in BOTH {
        let a = tracer.trace(&pts, &nrm, &params(e, 32)).unwrap();
        let b = tracer.trace(&pts, &nrm, &params(e, 32)).unwrap();
        assert_eq!(a, b);
        let c = tracer
            .trace(
                &pts,
                &nrm,
                &AoParams {
                    seed: 8,
                    ..params(e, 32)
                },
            )
            .unwrap();
        assert_ne!(a.ao, c.ao);
        // Under the slab AO is low, beyond its edge it opens up.
        assert!(a.ao[30] < a.ao[63], "{e:?}");
    }
    // An empty scene is open everywhere.
    let empty = AoTracer::new(&[]);
    assert!(
        empty
            .trace(&pts, &nrm, &params(Estimator::ClosestHit, 8))
            .unwrap()
            .ao
            .iter()
            .all(|&a| a == 1.0)
    );
}

#[test]
fn results_do_not_depend_on_threads_or_batch() {
    let mut scene = Scene::default();
    scene.add(
        Mesh::cuboid(Vec3::new(-1.0, -1.0, 0.2), Vec3::new(1.0, 1.0, 0.5)).subdivided(2),
        Affine3A::IDENTITY,
    );
    let tracer = AoTracer::new(&scene.world_triangles().unwrap());
    let pts: Vec<Vec3> = (0..200)
        .map(|i| Vec3::new(i as f32 * 0.015 - 1.5, (i % 7) as f32 * 0.1, 0.0))
        .collect();
    let nrm = vec![Vec3::Z; pts.len()];
    for e in BOTH {
        let p = params(e, 16);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| tracer.trace(&pts, &nrm, &p).unwrap())
        };
        assert_eq!(run(1), run(2));
        // A subset traced under the same ids gets the same values.
        let ids: Vec<u32> = (50..60).collect();
        let sub = tracer
            .trace_ids(&ids, &pts[50..60], &nrm[50..60], &p)
            .unwrap();
        assert_eq!(sub.ao, run(2).ao[50..60]);
    }
}

#[test]
fn bad_input_is_refused() {
    let tracer = AoTracer::new(&[[Vec3::ZERO, Vec3::X, Vec3::Y]]);
    let pts = [Vec3::ZERO; 3];
    assert_eq!(
        tracer.trace(&pts, &[Vec3::Z; 2], &AoParams::default()),
        Err(SceneError::LengthMismatch {
            points: 3,
            normals: 2
        })
    );
    for bad in [
        AoParams {
            radius: 0.0,
            ..AoParams::default()
        },
        AoParams {
            radius: f32::NAN,
            ..AoParams::default()
        },
        AoParams {
            bias: -1.0,
            ..AoParams::default()
        },
        AoParams {
            rays: MAX_RAYS + 1,
            ..AoParams::default()
        },
    ] {
        assert!(matches!(
            tracer.trace(&pts, &[Vec3::Z; 3], &bad),
            Err(SceneError::Parameter { .. })
        ));
    }
    // Far from the origin the ray offset still clears the surface.
    let far = Vec3::new(1e4, 1e4, 0.0);
    let mut scene = Scene::default();
    scene.add(
        Mesh::quad(
            far - Vec3::new(5.0, 5.0, 0.0),
            Vec3::X * 10.0,
            Vec3::Y * 10.0,
        ),
        Affine3A::IDENTITY,
    );
    let tracer = AoTracer::new(&scene.world_triangles().unwrap());
    let r = tracer
        .trace(&[far], &[Vec3::Z], &params(Estimator::ClosestHit, 64))
        .unwrap();
    assert_eq!(r.ao, vec![1.0]);
}
