//! A backend that casts single rays (`AoBackend::casts_rays`) follows the
//! CPU tracer's rules, checked without a GPU: a backend on the host, one
//! BVH over the scene's world triangles as the pipeline places them, each
//! ray scored as `PointRays::score` scores it. Kept ray scores on it give
//! the frames of whole points (ray reuse is exact), early decisions run on
//! it in rounds, and a backend that hands back a wrong count of scores is
//! a typed error.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Affine3A, Vec3};
use psao_scene::*;

/// The host backend: `single` says whether it casts single rays; `short`
/// makes it hand back one score too few (a faulty backend).
struct HostBackend {
    scene: Scene,
    tracer: AoTracer,
    single: bool,
    short: bool,
    /// Rounds of single rays asked for (shared with the test).
    rounds: Arc<AtomicU64>,
}

impl HostBackend {
    fn new(scene: &Scene, single: bool) -> HostBackend {
        HostBackend {
            scene: scene.clone(),
            tracer: AoTracer::new(&[]),
            single,
            short: false,
            rounds: Arc::default(),
        }
    }
}

impl AoBackend for HostBackend {
    fn name(&self) -> String {
        "host".into()
    }

    fn place(
        &mut self,
        transforms: &[Affine3A],
        vertices: &[Option<&[Vec3]>],
    ) -> Result<(), SceneError> {
        let mut triangles = Vec::new();
        for (i, instance) in self.scene.instances.iter().enumerate() {
            let mesh = &self.scene.meshes[instance.mesh];
            let positions = vertices[i].unwrap_or(&mesh.positions);
            let world = |v: u32| transforms[i].transform_point3(positions[v as usize]);
            for t in mesh.indices.chunks_exact(3) {
                triangles.push([world(t[0]), world(t[1]), world(t[2])]);
            }
        }
        self.tracer = AoTracer::new(&triangles);
        Ok(())
    }

    fn trace_ids(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        params: &AoParams,
    ) -> Result<AoResult, SceneError> {
        self.tracer.trace_ids(ids, points, normals, params)
    }

    fn casts_rays(&self) -> bool {
        self.single
    }

    fn cast_rays(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        jobs: &[RayJob],
        params: &AoParams,
    ) -> Result<Vec<f32>, SceneError> {
        self.rounds.fetch_add(1, Ordering::Relaxed);
        let mut scores: Vec<f32> = jobs
            .iter()
            .map(|j| {
                let p = j.point as usize;
                PointRays::new(ids[p], points[p], normals[p], params)
                    .map_or(1.0, |r| r.score(&self.tracer, j.ray))
            })
            .collect();
        if self.short {
            scores.pop();
        }
        Ok(scores)
    }
}

fn config(budget: RayBudget, early: bool) -> PipelineConfig {
    PipelineConfig {
        density: 24.0,
        ao: AoParams {
            rays: 16,
            ..AoParams::default()
        },
        budget,
        early: early.then(EarlyDecisions::default),
        ..PipelineConfig::default()
    }
}

/// Every frame's bytes and the reports over `ticks` steps of 1/30 s.
fn run(p: &mut Pipeline, ticks: u32) -> (Vec<Vec<u8>>, Vec<FrameReport>) {
    let mut frames = vec![p.keyframe().unwrap().bytes.to_vec()];
    let mut reports = Vec::new();
    for _ in 0..ticks {
        let (f, r) = p.step(1.0 / 30.0).unwrap();
        frames.push(f.map(|f| f.bytes.to_vec()).unwrap_or_default());
        reports.push(r);
    }
    (frames, reports)
}

/// A pipeline on the host backend, and the count of its rounds of single
/// rays.
fn on_counted(scene: &Scene, c: PipelineConfig, single: bool) -> (Pipeline, Arc<AtomicU64>) {
    let backend = HostBackend::new(scene, single);
    let rounds = backend.rounds.clone();
    let p = Pipeline::with_backend(scene.clone(), c, Box::new(backend)).unwrap();
    (p, rounds)
}

fn on(scene: &Scene, c: PipelineConfig, single: bool) -> Pipeline {
    on_counted(scene, c, single).0
}

#[test]
fn single_rays_with_kept_scores_send_the_frames_of_whole_points() {
    let scene = default_scene();
    let c = config(RayBudget::Unlimited, false);
    let (whole, rw) = run(&mut on(&scene, c.clone(), false), 20);
    let (mut p, rounds) = on_counted(&scene, c, true);
    let (single, rs) = run(&mut p, 20);
    // One round a step: every point's rays at once.
    let rounds = rounds.load(Ordering::Relaxed);
    assert!((1..=20).contains(&rounds), "{rounds} rounds");
    assert_eq!(whole, single, "ray reuse is exact on a backend too");
    let sum = |r: &[FrameReport], f: fn(&FrameReport) -> u64| r.iter().map(f).sum::<u64>();
    let (rays_whole, rays_single) = (sum(&rw, |r| r.rays), sum(&rs, |r| r.rays));
    assert!(
        rays_single < rays_whole,
        "{rays_single} rays cast over kept scores against {rays_whole}"
    );
    assert!(sum(&rs, |r| r.rays_kept) > 0);
    assert_eq!(sum(&rw, |r| r.rays_kept), 0, "whole points keep no scores");
}

#[test]
fn early_decisions_run_on_a_backend_that_casts_single_rays_in_rounds() {
    let scene = default_scene();
    let c = config(RayBudget::Rays(1500), true);
    let (mut p, rounds) = on_counted(&scene, c.clone(), true);
    let (frames, reports) = run(&mut p, 20);
    let early: u64 = reports.iter().map(|r| r.early).sum();
    assert!(early > 0, "no point stopped early");
    // Runs of a quarter of the rays at a time: more than one round a step.
    let rounds = rounds.load(Ordering::Relaxed);
    assert!(rounds > 20, "{rounds} rounds over 20 steps");
    // Deterministic: the same run again sends the same frames.
    let (again, _) = run(&mut on(&scene, c.clone(), true), 20);
    assert_eq!(frames, again);
    // A backend that casts no single rays makes no early decisions.
    let (_, plain) = run(&mut on(&scene, c, false), 20);
    assert_eq!(plain.iter().map(|r| r.early).sum::<u64>(), 0);
}

#[test]
fn a_backend_that_hands_back_too_few_scores_is_an_error() {
    let scene = default_scene();
    let mut backend = HostBackend::new(&scene, true);
    backend.short = true;
    let c = config(RayBudget::Unlimited, false);
    let mut p = Pipeline::with_backend(scene, c, Box::new(backend)).unwrap();
    p.keyframe().unwrap();
    let e = (0..10)
        .find_map(|_| p.step(1.0 / 30.0).err())
        .expect("a step fails");
    assert!(
        matches!(&e, SceneError::Backend { backend, reason } if backend == "host" && reason.contains("scores for")),
        "{e}"
    );
}
