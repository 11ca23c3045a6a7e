//! Why rays from the skinned figure were slow on lavapipe: the order in
//! which a mesh's triangles reach the BLAS builder. The same rays against
//! (1) the default scene's figure, in the scene and as a rigid copy alone,
//! and (2) spheres of growing triangle count, on the GPU (wgpu ray
//! queries) with the triangles as given and in median-split order
//! ([`TriangleOrder`]), and on the CPU (obvhs), same run, best of `--reps` (5).
//!
//! `cargo run --release -p psao-gpu --example gpu_mesh_size [-- --rays 64 --density 256 --reps 5]`

use glam::{Affine3A, Vec3};
use psao_eval::*;
use psao_gpu::{GpuAo, GpuContext, GpuScene, TriangleOrder};
use psao_scene::*;

mod support;

use support::arg;

/// Runs per timing (`--reps`, default 5); the fastest counts.
fn reps() -> u32 {
    arg("--reps", 5)
}

/// A UV sphere of radius 0.5 with `2 nu nv` triangles.
fn sphere(nu: u32, nv: u32) -> Mesh {
    let (mut positions, mut normals, mut indices) = (Vec::new(), Vec::new(), Vec::new());
    for j in 0..=nv {
        for i in 0..=nu {
            let theta = std::f32::consts::PI * j as f32 / nv as f32;
            let phi = std::f32::consts::TAU * i as f32 / nu as f32;
            let n = Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            );
            positions.push(n * 0.5);
            normals.push(n);
        }
    }
    for j in 0..nv {
        for i in 0..nu {
            let a = j * (nu + 1) + i;
            let c = a + nu + 1;
            indices.extend([a, c, a + 1, a + 1, c, c + 1]);
        }
    }
    Mesh {
        positions,
        normals,
        indices,
        double_sided: false,
        skin: None,
        morph: None,
        alpha: None,
    }
}

/// A scene of `meshes`, each placed once where it is.
fn scene_of(meshes: Vec<Mesh>) -> Scene {
    let mut s = Scene::default();
    for (mesh, m) in meshes.into_iter().enumerate() {
        s.meshes.push(m);
        s.instances.push(Instance {
            mesh,
            transform: Affine3A::IDENTITY,
            node: None,
            skin: None,
        });
    }
    s
}

/// Best-of-3 milliseconds on the GPU and on the CPU for the same rays.
struct Timer<'a> {
    ctx: &'a GpuContext,
    ao: GpuAo,
    params: AoParams,
}

impl Timer<'_> {
    fn gpu(&self, scene: &Scene, order: TriangleOrder, pts: &[Vec3], nrm: &[Vec3]) -> f64 {
        let gs = GpuScene::with_order(self.ctx, scene, order).expect("GPU scene");
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        let run = || {
            self.ao
                .trace_ids(self.ctx, &gs, &ids, pts, nrm, &self.params)
                .expect("gpu")
        };
        let _ = run(); // the driver compiles the shader on first use
        support::best_ms(reps(), || {
            run();
        })
    }

    fn cpu(&self, scene: &Scene, pts: &[Vec3], nrm: &[Vec3]) -> f64 {
        let tracer = PosedScene::new(scene, 0.0).expect("poses").tracer();
        let ids: Vec<u32> = (0..pts.len() as u32).collect();
        support::best_ms(reps(), || {
            tracer.trace_ids(&ids, pts, nrm, &self.params).expect("cpu");
        })
    }

    /// One table row: both triangle orders on the GPU and the CPU.
    fn row(&self, name: &str, tris: usize, scene: &Scene, pts: &[Vec3], nrm: &[Vec3]) {
        let given = self.gpu(scene, TriangleOrder::AsGiven, pts, nrm);
        let median = self.gpu(scene, TriangleOrder::MedianSplit, pts, nrm);
        let cpu = self.cpu(scene, pts, nrm);
        println!(
            "| {name} | {tris} | {} | {given:.1} | {median:.1} | {cpu:.1} | {:.2}x | {:.2}x | {:.2}x |",
            pts.len(),
            given / cpu,
            median / cpu,
            given / median
        );
    }
}

fn main() {
    let rays: u32 = arg("--rays", 64);
    let density: f32 = arg("--density", 256.0);
    let ctx = support::open_context();
    let t = Timer {
        ctx: &ctx,
        ao: GpuAo::new(&ctx).expect("AO pass"),
        params: AoParams {
            rays,
            ..AoParams::default()
        },
    };
    println!("{rays} closest-hit rays per point; GPU: {}", ctx.describe());
    println!(
        "| case | triangles | points | GPU as given ms | GPU median-split ms | CPU ms | as given / CPU | median-split / CPU | as given / median-split |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");

    // (1) The figure of the default scene: in the scene, and a rigid copy
    // of it (its pose-0 vertices as an ordinary mesh) alone.
    let scene = default_scene();
    let p = support::default_pipeline(&scene, density);
    let (pos, n) = p.current_points(WALKER).expect("walker points");
    let tf = p.transform(WALKER).expect("walker transform");
    let nm = tf.matrix3.inverse().transpose();
    let take = pos.len().min(1200);
    let pts: Vec<Vec3> = pos[..take]
        .iter()
        .map(|q| tf.transform_point3(*q))
        .collect();
    let nrm: Vec<Vec3> = n[..take].iter().map(|q| (nm * *q).normalize()).collect();
    let mesh = &scene.meshes[scene.instances[WALKER].mesh];
    let tris = mesh.triangle_count();
    t.row(
        "default scene, rays from the figure",
        tris,
        &scene,
        &pts,
        &nrm,
    );
    let (skinned_pos, skinned_nrm) = scene.deformed(WALKER, &scene.pose(0.0));
    let mut alone = scene_of(vec![Mesh {
        positions: skinned_pos.to_vec(),
        normals: skinned_nrm.to_vec(),
        skin: None,
        ..mesh.clone()
    }]);
    alone.instances[0].transform = scene.pose(0.0).instances[WALKER];
    t.row("the figure alone, rigid", tris, &alone, &pts, &nrm);

    // (2) Spheres: 2000 points on the surface, rays into the inside.
    let k = 2000;
    let pts: Vec<Vec3> = (0..k)
        .map(|i| {
            let a = i as f32 * 2.399_963;
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / k as f32;
            let r = (1.0 - z * z).sqrt();
            Vec3::new(r * a.cos(), z, r * a.sin()) * 0.499
        })
        .collect();
    let nrm: Vec<Vec3> = pts.iter().map(|q| -q.normalize()).collect();
    for (nu, nv) in [(8, 4), (32, 16), (64, 40), (128, 80)] {
        let m = sphere(nu, nv);
        let tris = m.triangle_count();
        t.row(
            "UV sphere, rays inwards",
            tris,
            &scene_of(vec![m]),
            &pts,
            &nrm,
        );
    }
}
