//! The server frame pipeline for scenes with rigid motion (paper 3.3):
//! move instances -> choose the points to re-trace -> trace -> compare with
//! what clients hold (thresholds) -> GridTable -> Encoder.
//!
//! Skipping what the scene does not need is part of the design:
//! - a rigidly moving instance sends only its transform; its own points are
//!   re-traced (their surroundings changed) but sent only if their AO moved
//!   past the threshold;
//! - a static instance is re-traced only where its points lie within reach
//!   (the AO radius) of a moving instance's swept bounds;
//! - a frame with nothing to say is not sent.

use std::time::{Duration, Instant};

use glam::{Affine3A, Mat3A, Vec3};
use psao_codec::{EncodedFrame, Encoder, EncoderConfig, GridTable, Thresholds};

use crate::ao::{AoParams, AoTracer, ray_offset};
use crate::error::SceneError;
use crate::layout::{LayoutParams, layout};
use crate::points::{PointSet, generate_points};
use crate::scene::{Scene, transformed_bounds};

/// How an instance moves: a function of time (seconds) to its
/// local-to-world transform. `None` for a static instance.
pub type Motion = Option<Box<dyn Fn(f32) -> Affine3A + Send + Sync>>;

/// Pipeline settings.
#[derive(Clone, Debug, PartialEq)]
pub struct PipelineConfig {
    /// Points spawned per unit area (half are kept).
    pub density: f32,
    /// Seed of point generation.
    pub seed: u64,
    /// AO tracing.
    pub ao: AoParams,
    /// When a point is sent again.
    pub thresholds: Thresholds,
    /// Grid layout.
    pub layout: LayoutParams,
    /// Frame encoding.
    pub encoder: EncoderConfig,
    /// Re-trace only what motion can reach (true), or every point every
    /// frame (false: the baseline the skipping is measured against).
    pub skip: bool,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            density: 64.0,
            seed: 1,
            ao: AoParams {
                rays: 64,
                ..AoParams::default()
            },
            thresholds: Thresholds::default(),
            layout: LayoutParams::default(),
            encoder: EncoderConfig::default(),
            skip: true,
        }
    }
}

/// What one server frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameReport {
    /// Points in the scene.
    pub points: u64,
    /// Points re-traced.
    pub traced: u64,
    /// Rays cast.
    pub rays: u64,
    /// Points whose change passed the thresholds (set in their table).
    pub updated: u64,
    /// Transforms sent.
    pub transforms: u32,
    /// Bytes of the frame sent (0 when none was).
    pub bytes: u64,
    /// Time to move instances and rebuild the BVH.
    pub t_scene: Duration,
    /// Time to trace.
    pub t_trace: Duration,
    /// Time to update tables and encode.
    pub t_encode: Duration,
}

struct InstanceState {
    points: PointSet,
    table: GridTable,
    transform: Affine3A,
    transform_seq: u32,
    /// Local bounds of the mesh.
    bounds: (Vec3, Vec3),
}

/// A server streaming one scene.
pub struct Pipeline {
    scene: Scene,
    motions: Vec<Motion>,
    config: PipelineConfig,
    instances: Vec<InstanceState>,
    encoder: Encoder,
    time: f32,
    frame: u64,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline")
            .field("instances", &self.instances.len())
            .field("time", &self.time)
            .field("frame", &self.frame)
            .finish()
    }
}

fn overlaps(a: (Vec3, Vec3), b: (Vec3, Vec3)) -> bool {
    a.0.cmple(b.1).all() && b.0.cmple(a.1).all()
}

fn normal_matrix(t: &Affine3A) -> Mat3A {
    t.matrix3.inverse().transpose()
}

impl Pipeline {
    /// Generates points for every instance, lays out their grids and traces
    /// every point once (the state the first keyframe carries). `motions`
    /// has one entry per instance (missing entries are static).
    pub fn new(
        scene: Scene,
        mut motions: Vec<Motion>,
        config: PipelineConfig,
    ) -> Result<Pipeline, SceneError> {
        scene.validate()?;
        config.ao.validate()?;
        motions.resize_with(scene.instances.len(), || None);
        let mut instances = Vec::with_capacity(scene.instances.len());
        for (i, inst) in scene.instances.iter().enumerate() {
            let mesh = &scene.meshes[inst.mesh];
            let seed = config.seed ^ ((i as u64) << 32);
            let points = generate_points(mesh, config.density, seed)?;
            let bounds = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
            let sides = if mesh.double_sided { 2.0 } else { 1.0 };
            let def = layout(
                i,
                bounds,
                mesh.area() * sides,
                points.len(),
                points.radius.max(1e-6),
                &config.layout,
            )?;
            let table = GridTable::new(i as u32, def, points.len().max(1) as u32)?;
            let transform = motions[i].as_ref().map_or(inst.transform, |m| m(0.0));
            instances.push(InstanceState {
                points,
                table,
                transform,
                transform_seq: 0,
                bounds,
            });
        }
        let mut pipeline = Pipeline {
            scene,
            motions,
            encoder: Encoder::new(config.encoder),
            config,
            instances,
            time: 0.0,
            frame: 0,
        };
        let all: Vec<Vec<u32>> = pipeline
            .instances
            .iter()
            .map(|s| (0..s.points.len() as u32).collect())
            .collect();
        let tracer = pipeline.tracer()?;
        pipeline.trace_and_update(&tracer, &all, true)?;
        for s in &mut pipeline.instances {
            s.table.take_dirty();
        }
        Ok(pipeline)
    }

    /// Seconds of scene time so far.
    pub fn time(&self) -> f32 {
        self.time
    }

    /// The table of instance `i`.
    pub fn table(&self, i: usize) -> Option<&GridTable> {
        self.instances.get(i).map(|s| &s.table)
    }

    /// Number of instances.
    pub fn instance_count(&self) -> usize {
        self.instances.len()
    }

    /// The points of instance `i` (local space).
    pub fn points(&self, i: usize) -> Option<&PointSet> {
        self.instances.get(i).map(|s| &s.points)
    }

    /// World transform of instance `i` now.
    pub fn transform(&self, i: usize) -> Option<Affine3A> {
        self.instances.get(i).map(|s| s.transform)
    }

    /// A keyframe of the current state (for a client joining now).
    pub fn keyframe(&mut self) -> Result<EncodedFrame, SceneError> {
        let mut kf = self.encoder.keyframe();
        for s in &self.instances {
            kf.snapshot(&s.table)?;
            kf.transform(s.table.id(), s.transform_seq, &s.transform.to_cols_array());
        }
        // A keyframe is always a frame (finish returns None only for empty
        // deltas).
        kf.finish()?
            .ok_or(SceneError::Encode(psao_codec::EncodeError::FrameTooLarge))
    }

    fn tracer(&self) -> Result<AoTracer, SceneError> {
        let mut tris = Vec::new();
        for (s, inst) in self.instances.iter().zip(&self.scene.instances) {
            let m = &self.scene.meshes[inst.mesh];
            for t in 0..m.triangle_count() {
                tris.push(m.triangle(t).map(|p| s.transform.transform_point3(p)));
            }
        }
        Ok(AoTracer::new(&tris))
    }

    /// Traces the listed points of each instance (world space) and sets the
    /// ones past the thresholds (all of them with `force`). Returns (traced,
    /// rays, updated).
    fn trace_and_update(
        &mut self,
        tracer: &AoTracer,
        which: &[Vec<u32>],
        force: bool,
    ) -> Result<(u64, u64, u64), SceneError> {
        let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
        let mut base = 0u32;
        let mut bases = Vec::with_capacity(self.instances.len());
        for (s, list) in self.instances.iter().zip(which) {
            bases.push(base);
            let nm = normal_matrix(&s.transform);
            for &k in list {
                ids.push(base + k);
                pts.push(s.transform.transform_point3(s.points.positions[k as usize]));
                nrm.push((nm * s.points.normals[k as usize]).normalize_or_zero());
            }
            base += s.points.len() as u32;
        }
        let result = tracer.trace_ids(&ids, &pts, &nrm, &self.config.ao)?;
        let mut updated = 0u64;
        let mut at = 0usize;
        let th = self.config.thresholds;
        for (s, list) in self.instances.iter_mut().zip(which) {
            for &k in list {
                let (p, n) = (s.points.positions[k as usize], s.points.normals[k as usize]);
                let ao = result.ao[at];
                at += 1;
                let set = if force {
                    s.table.set_point(k, p, n, ao).map(|_| true)
                } else {
                    s.table.update_point(k, p, n, ao, &th)
                };
                if set? {
                    updated += 1;
                }
            }
        }
        Ok((ids.len() as u64, result.rays, updated))
    }

    /// Advances the scene by `dt` seconds and produces the frame clients
    /// need, if any.
    pub fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, FrameReport), SceneError> {
        let t0 = Instant::now();
        self.time += dt;
        self.frame += 1;
        // A ray reaches R beyond its origin, which sits `ray_offset` off the
        // surface: grow boxes by both (the offset at the box's farthest
        // corner), plus a millimetre of slack.
        let ao = self.config.ao;
        let grow = |b: (Vec3, Vec3)| {
            let far = b.0.abs().max(b.1.abs());
            let reach = ao.radius + ray_offset(ao.bias, far) + 1e-3;
            (b.0 - Vec3::splat(reach), b.1 + Vec3::splat(reach))
        };
        // Move instances; remember where motion happened (swept bounds).
        let mut moved = vec![false; self.instances.len()];
        let mut swept = Vec::new();
        for (i, s) in self.instances.iter_mut().enumerate() {
            let Some(m) = &self.motions[i] else { continue };
            let next = m(self.time);
            if next == s.transform {
                continue;
            }
            let before = transformed_bounds(&s.transform, s.bounds);
            let after = transformed_bounds(&next, s.bounds);
            swept.push(grow((before.0.min(after.0), before.1.max(after.1))));
            s.transform = next;
            s.transform_seq = s.transform_seq.wrapping_add(1);
            moved[i] = true;
        }
        let mut report = FrameReport {
            points: self.instances.iter().map(|s| s.points.len() as u64).sum(),
            ..FrameReport::default()
        };
        // Choose the points to re-trace.
        let mut which: Vec<Vec<u32>> = vec![Vec::new(); self.instances.len()];
        let everything = !self.config.skip;
        if everything {
            for (w, s) in which.iter_mut().zip(&self.instances) {
                *w = (0..s.points.len() as u32).collect();
            }
        } else if !swept.is_empty() {
            for (i, s) in self.instances.iter().enumerate() {
                if moved[i] {
                    which[i] = (0..s.points.len() as u32).collect();
                    continue;
                }
                let wb = transformed_bounds(&s.transform, s.bounds);
                if !swept.iter().any(|&b| overlaps(b, grow(wb))) {
                    continue;
                }
                which[i] = (0..s.points.len() as u32)
                    .filter(|&k| {
                        let p = s.transform.transform_point3(s.points.positions[k as usize]);
                        swept
                            .iter()
                            .any(|b| p.cmpge(b.0).all() && p.cmple(b.1).all())
                    })
                    .collect();
            }
        }
        let tracer = if swept.is_empty() && !everything {
            None
        } else {
            Some(self.tracer()?)
        };
        report.t_scene = t0.elapsed();
        let t1 = Instant::now();
        if let Some(tracer) = &tracer {
            let (traced, rays, updated) = self.trace_and_update(tracer, &which, false)?;
            report.traced = traced;
            report.rays = rays;
            report.updated = updated;
        }
        report.t_trace = t1.elapsed();
        let t2 = Instant::now();
        let mut frame = self.encoder.delta();
        for (i, s) in self.instances.iter_mut().enumerate() {
            if moved[i] {
                frame.transform(s.table.id(), s.transform_seq, &s.transform.to_cols_array());
                report.transforms += 1;
            }
            frame.changes(&mut s.table);
        }
        let frame = frame.finish()?;
        report.bytes = frame.as_ref().map_or(0, |f| f.bytes.len() as u64);
        report.t_encode = t2.elapsed();
        Ok((frame, report))
    }
}
