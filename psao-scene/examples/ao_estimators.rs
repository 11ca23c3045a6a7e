//! Rays per second and error of the two AO estimators on the same points.
//!
//! A room (floor, three walls), four columns, a table and a thin railing;
//! points generated at 64 per square metre (32 kept). The reference is the
//! closest-hit estimator with 4096 rays per point. For each estimator and
//! ray count: wall time (median of 3), Mrays/s, RMSE against the reference,
//! and Monte Carlo efficiency 1 / (RMSE^2 x time), whose ratio says which
//! estimator reaches a given error sooner.
//!
//! `cargo run --release -p psao-scene --example ao_estimators [LEVELS]`
//! (LEVELS: midpoint subdivisions of every triangle, default 5), or with
//! `default` (the default scene at time 0, traced as the server pipeline
//! traces it) or `cesium` (CesiumMan standing on a floor) instead.

use std::time::Instant;

use glam::{Affine3A, Vec3};
use psao_scene::*;

fn room(levels: u32) -> Scene {
    let mut s = Scene::default();
    let id = Affine3A::IDENTITY;
    s.add(Mesh::quad(Vec3::ZERO, Vec3::Z * 8.0, Vec3::X * 8.0), id);
    s.add(Mesh::quad(Vec3::ZERO, Vec3::X * 8.0, Vec3::Y * 3.0), id);
    s.add(Mesh::quad(Vec3::ZERO, Vec3::Y * 3.0, Vec3::Z * 8.0), id);
    s.add(
        Mesh::quad(Vec3::new(8.0, 0.0, 0.0), Vec3::Z * 8.0, Vec3::Y * 3.0),
        id,
    );
    for (x, z) in [(2.0, 2.0), (6.0, 2.0), (2.0, 6.0), (6.0, 6.0)] {
        let column = Mesh::cuboid(Vec3::new(-0.15, 0.0, -0.15), Vec3::new(0.15, 3.0, 0.15));
        s.add(column, Affine3A::from_translation(Vec3::new(x, 0.0, z)));
    }
    s.add(
        Mesh::cuboid(Vec3::new(3.5, 0.0, 3.5), Vec3::new(4.5, 0.8, 4.0)),
        id,
    );
    s.add(
        Mesh::cuboid(Vec3::new(1.0, 1.0, 7.0), Vec3::new(7.0, 1.05, 7.05)),
        id,
    );
    for m in &mut s.meshes {
        *m = m.subdivided(levels);
    }
    s
}

/// The tracer and world-space points of a server pipeline on `scene`, as
/// its first frame traces them.
fn from_pipeline(scene: Scene) -> (AoTracer, Vec<Vec3>, Vec<Vec3>) {
    let config = PipelineConfig {
        ao: AoParams {
            rays: 1,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let mut p = Pipeline::new(scene, config).expect("valid scene");
    let (mut pts, mut nrm) = (Vec::new(), Vec::new());
    for i in 0..p.instance_count() {
        let (pos, n) = p.current_points(i).expect("instance");
        let t = p.transform(i).expect("instance");
        let nm = t.matrix3.inverse().transpose();
        pts.extend(pos.iter().map(|q| t.transform_point3(*q)));
        nrm.extend(n.iter().map(|q| (nm * *q).normalize()));
    }
    (p.current_tracer(), pts, nrm)
}

fn main() {
    let which = std::env::args().nth(1).unwrap_or_default();
    let (tracer, pts, nrm) = match which.as_str() {
        "default" => from_pipeline(default_scene()),
        "cesium" => {
            let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/CesiumMan.glb");
            let mut s = load_gltf(std::path::Path::new(path)).expect("CesiumMan loads");
            s.add(
                Mesh::quad(Vec3::new(-3.0, 0.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0),
                Affine3A::IDENTITY,
            );
            from_pipeline(s)
        }
        _ => {
            // Subdivision levels: 0 = 80 triangles, 5 = 81,920 (same surfaces).
            let levels = which.parse().unwrap_or(5);
            let scene = room(levels);
            scene.validate().expect("valid scene");
            let (mut pts, mut nrm) = (Vec::new(), Vec::new());
            for (i, inst) in scene.instances.iter().enumerate() {
                let set =
                    generate_points(&scene.meshes[inst.mesh], 64.0, i as u64).expect("points");
                pts.extend(
                    set.positions
                        .iter()
                        .map(|p| inst.transform.transform_point3(*p)),
                );
                nrm.extend(
                    set.normals
                        .iter()
                        .map(|n| inst.transform.transform_vector3(*n).normalize()),
                );
            }
            let triangles = scene.world_triangles().expect("valid scene");
            (AoTracer::new(&triangles), pts, nrm)
        }
    };
    let base = AoParams {
        seed: 1,
        ..AoParams::default()
    };
    let t = Instant::now();
    let reference_params = AoParams {
        rays: 4096,
        seed: 999,
        ..base
    };
    let reference = tracer
        .trace(&pts, &nrm, &reference_params)
        .expect("valid parameters");
    println!(
        "{} points, {} triangles, {} threads; reference: closest hit, 4096 rays/point, {:.1} s",
        pts.len(),
        tracer.triangles(),
        rayon::current_num_threads(),
        t.elapsed().as_secs_f64()
    );
    println!();
    println!(
        "| estimator | rays/point | time (s) | Mrays/s | RMSE vs reference | efficiency 1/(RMSE^2 s) |"
    );
    println!("|---|---|---|---|---|---|");
    let mut eff = Vec::new();
    for rays in [32u32, 128, 512] {
        for (name, estimator) in [
            ("closest hit", Estimator::ClosestHit),
            ("Laine-Karras", Estimator::LaineKarras),
        ] {
            let p = AoParams {
                rays,
                estimator,
                ..base
            };
            let mut times = Vec::new();
            let mut result = AoResult::default();
            for _ in 0..3 {
                let t = Instant::now();
                result = tracer.trace(&pts, &nrm, &p).expect("valid parameters");
                times.push(t.elapsed().as_secs_f64());
            }
            times.sort_by(f64::total_cmp);
            let time = times[1];
            let mse = result
                .ao
                .iter()
                .zip(&reference.ao)
                .map(|(a, r)| ((a - r) as f64).powi(2))
                .sum::<f64>()
                / pts.len() as f64;
            let e = 1.0 / (mse * time);
            eff.push((rays, name, e, result.rays as f64 / time));
            println!(
                "| {name} | {rays} | {time:.3} | {:.2} | {:.4} | {e:.0} |",
                result.rays as f64 / time / 1e6,
                mse.sqrt()
            );
        }
    }
    println!();
    for pair in eff.chunks(2) {
        println!(
            "{} rays/point: Laine-Karras / closest hit: {:.2}x rays per second, {:.2}x efficiency (time to equal error)",
            pair[0].0,
            pair[1].3 / pair[0].3,
            pair[1].2 / pair[0].2
        );
    }
}
