//! The server frame pipeline (paper 3.3): animate -> carry skinned points
//! along (in instance-local space, where they are traced) -> choose the
//! points to re-trace ->
//! trace -> compare with what clients hold (thresholds) -> GridTable ->
//! Encoder.
//!
//! Skipping what the scene does not need is part of the design:
//! - a rigidly moving instance sends only its transform; its own points are
//!   re-traced (their surroundings changed) but sent only if their AO moved
//!   past the threshold;
//! - a skinned (or morphing) instance re-traces its points when its pose
//!   changes; in bind space (point format 1, the default) its points never
//!   move and it sends those whose AO passed the threshold, posed
//!   ([`PipelineConfig::bind_space`] off) those whose position, normal or
//!   AO did;
//! - a static instance is re-traced only where its points lie within reach
//!   (the AO radius) of a moving instance's swept bounds;
//! - with per-viewer culling, points outside the viewer's extended frustum
//!   wait until they come into view;
//! - static geometry sits in a BVH built once; only the moving part is
//!   rebuilt;
//! - a frame with nothing to say is not sent.
//!
//! Here are the pipeline's state, its creation (points, grids and the
//! first trace of every point) and its accessors; [`config`] holds the
//! settings, [`step`] one frame in its phases, [`bvh`] the BVHs it traces
//! against, [`dirty`] the tracing and thresholds that make the dirty set,
//! [`backend`] the [`AoBackend`] it may trace on instead, [`work`] what
//! each chosen point casts (the same rules on either), and [`report`]
//! what a frame did.

pub(crate) mod backend;
mod blocks;
pub(crate) mod budget;
mod buried;
mod bvh;
mod choose;
pub(crate) mod config;
mod dirty;
pub(crate) mod early;
mod loops;
mod plan;
mod ray_cache;
mod reach;
pub(crate) mod report;
mod slots;
mod stage;
mod step;
mod trend;
mod work;

use std::sync::Arc;

use glam::{Affine3A, Vec3};
use psao_codec::{EncodedFrame, Encoder, GridTable};
use rayon::prelude::*;

use crate::error::{SceneError, check_param};
use crate::model::alpha::AlphaMask;
use crate::model::pose::Pose;
use crate::model::scene::{Instance, Scene, check_transform};
use crate::points::generate::{PointSet, check_density, generate_points_with};
use crate::points::layout::{fit_to_points, layout};
use crate::precision::check_precision;
use crate::trace::ao::AoTracer;
use crate::trace::geometry::TriangleBvh;
use backend::AoBackend;
use config::{PipelineConfig, Views};

/// One instance as the pipeline holds it: its points, its pose now, its
/// table (what clients hold) and its BVH.
struct InstanceState {
    /// Points in the mesh's bind pose.
    points: PointSet,
    /// Points now (instance-local), for a deforming (skinned or morphing)
    /// instance, which moves them; empty for a rigid one, whose points are `points`' own (see
    /// [`InstanceState::now`]).
    positions: Vec<Vec3>,
    /// Point normals now (empty for a rigid instance, as `positions`).
    normals: Vec<Vec3>,
    /// Deformed vertex positions and normals now (empty: the mesh's own).
    vertices: Vec<Vec3>,
    vertex_normals: Vec<Vec3>,
    /// Room to skin into before the new pose is known to be sound.
    scratch_vertices: Vec<Vec3>,
    scratch_normals: Vec<Vec3>,
    /// Joint matrices of the current pose (skinned instances; with
    /// `weights`, what `vertices` were deformed with).
    joints: Vec<Affine3A>,
    /// The morph weights `vertices` were made with (empty without
    /// animated morph targets).
    weights: Vec<f32>,
    table: GridTable,
    transform: Affine3A,
    transform_seq: u32,
    /// The transform clients hold, and its sequence: `transform` once sent,
    /// or, for a rigid mover held whole under a budget
    /// ([`PipelineConfig::movers_whole`]), the pose its points were last
    /// traced in together.
    sent_transform: Affine3A,
    sent_seq: u32,
    /// Steps a rigid mover held whole has had points to trace without
    /// being traced (see `choose::whole_movers`).
    held_steps: u32,
    /// Local bounds of the mesh as it is now.
    bounds: (Vec3, Vec3),
    /// Whether it can move or deform.
    dynamic: bool,
    /// Points waiting to be traced until they come into view.
    pending: Vec<bool>,
    /// Each point's AO as its last trace gave it, quantized (what the
    /// settle rule compares with, and which points planning tests for
    /// being open; the held AO after setup).
    last_ao: Vec<u8>,
    /// Each point's trend, for the ray budget's priority (empty without
    /// a budget).
    trend: Vec<trend::Trend>,
    /// How fast its points' AO moved lately, by cell (with `trend`, and
    /// noted only for a rigid instance that can move).
    heat: trend::Heat,
    /// How much its own AO depends on its pose (noted only for a rigid
    /// instance that can move, under a budget).
    pose: trend::PoseDependence,
    /// Its own BVH in local space (dynamic instances, split BVH): moved by
    /// its transform, refitted when it deforms.
    bvh: Option<Arc<TriangleBvh>>,
    /// Its buried points and their donors (none found yet, or none).
    buried: buried::Buried,
    /// Its points in blocks (a rigid instance's; empty for a deforming
    /// one, whose points move).
    blocks: blocks::PointBlocks,
    /// Whether its table holds the points in the mesh's bind space (point
    /// format 1: a deforming instance with
    /// [`PipelineConfig::bind_space`]), where they never move.
    bind: bool,
}

/// Skinned instances on one node with one skin (the primitives of one
/// skinned glTF mesh): they deform together and, while their transforms
/// agree, are traced as one layer, one refittable BVH over all their
/// triangles, instead of a layer each.
struct SkinGroup {
    /// The instances, ascending.
    members: Vec<usize>,
    /// The BVH over the members' triangles in their shared local space.
    bvh: Option<Arc<TriangleBvh>>,
}

/// The groups of `scene`'s dynamic skinned instances that share a node and
/// a skin, of two or more.
fn skin_groups(scene: &Scene, dynamic: &[bool]) -> Vec<SkinGroup> {
    let mut by_key: std::collections::BTreeMap<(usize, usize), Vec<usize>> = Default::default();
    for (i, inst) in scene.instances.iter().enumerate() {
        let skinned = scene.meshes[inst.mesh].skin.is_some();
        if let (true, true, Some(node), Some(skin)) = (dynamic[i], skinned, inst.node, inst.skin) {
            by_key.entry((node, skin)).or_default().push(i);
        }
    }
    by_key
        .into_values()
        .filter(|m| m.len() >= 2)
        .map(|members| SkinGroup { members, bvh: None })
        .collect()
}

impl InstanceState {
    /// Whether it keeps and reads `heat`: a rigid instance (its points
    /// never move in its local space) that can move.
    fn keeps_heat(&self) -> bool {
        self.rigid_mover()
    }

    /// Whether it is a rigid part that can move (its points never move in
    /// its local space), which a budget may hold whole.
    fn rigid_mover(&self) -> bool {
        self.dynamic && self.positions.is_empty()
    }

    /// Positions and normals of the points now (instance-local).
    fn now(&self) -> (&[Vec3], &[Vec3]) {
        if self.positions.is_empty() {
            (&self.points.positions, &self.points.normals)
        } else {
            (&self.positions, &self.normals)
        }
    }

    /// Positions and normals of the points as its table stores them: in
    /// bind space for a bind-space instance, else as [`Self::now`].
    fn stored(&self) -> (&[Vec3], &[Vec3]) {
        if self.bind {
            (&self.points.positions, &self.points.normals)
        } else {
            self.now()
        }
    }

    /// Bytes held for this instance: its points, skinned state, table and
    /// bookkeeping (capacities, not lengths).
    fn memory_bytes(&self) -> u64 {
        let v3 = std::mem::size_of::<Vec3>() as u64;
        let p = &self.points;
        (p.positions.capacity() + p.normals.capacity()) as u64 * v3
            + p.anchors.capacity() as u64
                * std::mem::size_of::<crate::points::generate::Anchor>() as u64
            + (self.positions.capacity()
                + self.normals.capacity()
                + self.vertices.capacity()
                + self.vertex_normals.capacity()
                + self.scratch_vertices.capacity()
                + self.scratch_normals.capacity()) as u64
                * v3
            + self.joints.capacity() as u64 * std::mem::size_of::<Affine3A>() as u64
            + self.weights.capacity() as u64 * 4
            + self.pending.capacity() as u64
            + self.last_ao.capacity() as u64
            + self.trend.capacity() as u64 * std::mem::size_of::<trend::Trend>() as u64
            + self.heat.memory_bytes()
            + self.table.memory_bytes()
            + self.buried.memory_bytes()
            + self.blocks.memory_bytes()
    }
}

/// Points the first trace traces per batch (and per progress report).
const TRACE_BATCH: u32 = 1 << 16;

/// Which part of [`Pipeline::with_progress`]'s setup is running.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SetupStage {
    /// Points, sample elimination and grid layout, per instance.
    Points,
    /// Probing for buried points, per instance.
    Buried,
    /// The first trace of every point, per point.
    Trace,
}

/// How far setup has come: `done` of `total` in `stage`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SetupProgress {
    /// The part running.
    pub stage: SetupStage,
    /// Units done (instances, or points traced).
    pub done: u64,
    /// Units in all.
    pub total: u64,
}

/// A server streaming one scene.
pub struct Pipeline {
    scene: Scene,
    config: PipelineConfig,
    /// Traces instead of the CPU tracer when set.
    backend: Option<Box<dyn AoBackend>>,
    instances: Vec<InstanceState>,
    masks: Vec<Option<Arc<AlphaMask>>>,
    encoder: Encoder,
    pose: Pose,
    /// Transforms set by [`Pipeline::place_instance`], overriding animation.
    overrides: Vec<Option<Affine3A>>,
    /// Instances placed since the last step: their transform is sent in the
    /// next frame even if it did not change, so that a placement is seen.
    placed: Vec<bool>,
    static_layer: Option<Arc<TriangleBvh>>,
    whole_layer: Option<Arc<TriangleBvh>>,
    /// Skinned instances that deform as one ([`SkinGroup`]).
    skin_groups: Vec<SkinGroup>,
    time: f64,
    frame: u64,
    /// What culling culls to.
    views: Views,
    /// Static points' ray scores from their last trace.
    ray_cache: ray_cache::RayCache,
    /// Points the ray budget put off to a later step.
    waiting: budget::Waiting,
    /// The boxes of what moved in each of the last steps that traced or
    /// had points waiting, with the step's number (wrapping at 2^32),
    /// oldest first: what the points planned late were reached by
    /// ([`Self::plan_late`]).
    moved: std::collections::VecDeque<(u32, reach::MotionBoxes)>,
    /// Moving points' ray scores from their last trace (early decisions).
    kept_scores: early::KeptScores,
    /// Each traced point's AO by the moment of the scene's loop (under a
    /// budget, where the animations loop together; see `loops`).
    loop_memory: Option<loops::LoopMemory>,
    /// The order early decisions cast a point's rays in.
    ray_order: Vec<u32>,
    /// Keys of the points that stopped early in the last step, ascending.
    last_early: Vec<u64>,
    /// Of those, the points whose instance stopped moving in this step
    /// (traced in full), ascending.
    early_rested: Vec<u64>,
    /// Rays a moving point eligible for early decisions cast on average
    /// in the last step that traced one: its cost under a budget.
    early_cost: f64,
    /// Keys of the points the last step traced (sorted): those the next
    /// leaves alone are settled.
    last_traced: Vec<u64>,
    /// Nanoseconds a ray costs, measured over the last steps (from setup's
    /// trace at first) per ray the budget paid for
    /// ([`budget::ns_per_priced_ray`]): what an automatic budget divides
    /// by.
    ray_ns: f64,
    /// Seconds a step takes besides casting once its budget is set
    /// (choosing the points, the waiting list, then tables, buried points,
    /// encoding), a running mean: what an automatic budget keeps aside.
    tail_s: f64,
    /// The bound on waiting in force under a budget: from
    /// [`PipelineConfig::max_wait`] up to
    /// [`PipelineConfig::max_wait_limit`], following demand.
    wait_bound: u32,
    /// The boxes of what moves, held from step to step while motion stays
    /// inside them.
    envelope: reach::Envelope,
    /// Per static point, what is known of its rays against the envelope
    /// (cleared with a new one): 0 nothing, 1 that it was planned once
    /// under it, `n + 2` that the rays of it that reach the envelope are
    /// `envelope_masks[n]` (found the second time it was planned). Only
    /// those are tested against a step's boxes, which lie inside it; a
    /// point with none needs no test while it holds (unless it waits or
    /// has stale rays).
    envelope_rays: slots::PointSlots,
    /// The masks `envelope_rays` points to, with the rays' directions.
    envelope_masks: Vec<plan::EnvelopeRays>,
    /// Per instance, a rigid mover traced whole over several steps at one
    /// pose ([`stage::Stage`]), if any.
    stages: Vec<Option<stage::Stage>>,
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

/// The bounds of `points`; a zero box without points.
fn bounds_of(points: &[Vec3]) -> (Vec3, Vec3) {
    crate::model::mesh::bounds_of(points).unwrap_or((Vec3::ZERO, Vec3::ZERO))
}

/// Density counts points per unit of world area: a rigid instance placed
/// by a scale (a model in millimetres under a node that scales by 1e-3)
/// gets as many points per square metre as any other. Per instance, the
/// world area per mesh area its points are made for: 1 for a skinned
/// instance (its mesh's own area), else [`world_area_scale`] at `pose`.
fn area_scales(scene: &Scene, pose: &Pose) -> Vec<f32> {
    (0..scene.instances.len())
        .into_par_iter()
        .map(|i| {
            let inst = &scene.instances[i];
            let mesh = &scene.meshes[inst.mesh];
            if inst.skin.is_some() && mesh.skin.is_some() {
                1.0
            } else {
                world_area_scale(mesh, &pose.instances[i])
            }
        })
        .collect()
}

/// Points the scene keeps at `density` (spawned per unit of world area,
/// half kept) with the instances' `area_scales`: an upper bound where
/// alpha masks cut holes; infinite where an area or a scale is.
fn estimated_points(scene: &Scene, area_scales: &[f32], density: f32) -> f64 {
    scene
        .instances
        .iter()
        .zip(area_scales)
        .map(|(inst, &scale)| {
            let mesh = &scene.meshes[inst.mesh];
            let sides = if mesh.double_sided { 2.0 } else { 1.0 };
            mesh.area() as f64 * sides * scale as f64 * density as f64 * 0.5
        })
        .map(|n| if n.is_nan() { f64::INFINITY } else { n })
        .sum()
}

/// World area per local area of `mesh` placed by `t` (exact per triangle:
/// a triangle of normal `n` grows by `|cof(M) n|`), 1 for a mesh without
/// area or a transform that keeps areas (within 1e-5: rotations and
/// translations).
fn world_area_scale(mesh: &crate::model::mesh::Mesh, t: &Affine3A) -> f32 {
    let m = glam::DMat3::from_cols(
        t.matrix3.x_axis.as_dvec3(),
        t.matrix3.y_axis.as_dvec3(),
        t.matrix3.z_axis.as_dvec3(),
    );
    // The cofactor matrix det(M) M^-T maps a face's area vector.
    let cof = m.inverse().transpose() * m.determinant();
    let (mut local, mut world) = (0.0f64, 0.0f64);
    for k in 0..mesh.triangle_count() {
        let [a, b, c] = mesh.triangle(k);
        let n = (b - a).cross(c - a).as_dvec3() * 0.5;
        local += n.length();
        world += (cof * n).length();
    }
    let scale = world / local;
    if local <= 0.0 || !scale.is_finite() || (scale - 1.0).abs() < 1e-5 {
        1.0
    } else {
        scale as f32
    }
}

/// Most poses sampled to find a skinned instance's bounds over its
/// animation.
const MAX_BOUND_SAMPLES: usize = 1800;

impl Pipeline {
    /// Generates points for every instance, lays out their grids and traces
    /// every point once (the state the first keyframe carries). Refuses a
    /// scene that f32 cannot place finely enough for its AO radius and
    /// point spacing ([`check_precision`]). Everything is set up in the
    /// first pose, time 0 plus the [`lead`](PipelineConfig::lead): its
    /// node scales also set how many points each instance gets.
    pub fn new(scene: Scene, config: PipelineConfig) -> Result<Pipeline, SceneError> {
        Pipeline::build(scene, config, None, &|_| {})
    }

    /// As [`new`](Self::new) (with `backend` if given, as
    /// [`with_backend`](Self::with_backend)), calling `progress` as setup
    /// goes: once per instance set up (points, layout; from several
    /// threads), then once per batch of 65,536 points traced. The result is
    /// the same as without it.
    pub fn with_progress(
        scene: Scene,
        config: PipelineConfig,
        backend: Option<Box<dyn AoBackend>>,
        progress: &(dyn Fn(SetupProgress) + Sync),
    ) -> Result<Pipeline, SceneError> {
        Pipeline::build(scene, config, backend, progress)
    }

    /// As [`new`](Self::new), with AO traced by `backend` (from the first
    /// trace on) instead of the CPU tracer.
    pub fn with_backend(
        scene: Scene,
        config: PipelineConfig,
        backend: Box<dyn AoBackend>,
    ) -> Result<Pipeline, SceneError> {
        Pipeline::build(scene, config, Some(backend), &|_| {})
    }

    /// The backend's name, or "cpu".
    pub fn backend_name(&self) -> String {
        self.backend.as_ref().map_or("cpu".into(), |b| b.name())
    }

    fn build(
        scene: Scene,
        config: PipelineConfig,
        backend: Option<Box<dyn AoBackend>>,
        progress: &(dyn Fn(SetupProgress) + Sync),
    ) -> Result<Pipeline, SceneError> {
        scene.validate()?;
        let total = scene.instances.len() as u64;
        let done = std::sync::atomic::AtomicU64::new(0);
        config.ao.validate()?;
        if let config::RayBudget::Auto { share } = config.budget {
            check_param("budget share", share as f64, 1e-6, 1.0, "in (0, 1]")?;
        }
        check_param("lead", config.lead as f64, 0.0, 1e3, "in [0, 1000] seconds")?;
        check_param(
            "max_wait",
            config.max_wait as f64,
            1.0,
            u32::MAX as f64,
            "at least 1 step",
        )?;
        check_param(
            "max_wait_limit",
            config.max_wait_limit as f64,
            config.max_wait as f64,
            u32::MAX as f64,
            "at least max_wait",
        )?;
        if let Some(e) = &config.early {
            check_param("early.z", e.z as f64, 0.0, 100.0, "in [0, 100]")?;
            check_param("early.sd_floor", e.sd_floor as f64, 0.0, 1.0, "in [0, 1]")?;
            check_param(
                "early.sd_floor_turning",
                e.sd_floor_turning as f64,
                0.0,
                1.0,
                "in [0, 1]",
            )?;
        }
        if let Some(c) = &config.cull {
            check_param("cull.aspect", c.aspect as f64, 1e-3, 1e3, "in [1e-3, 1e3]")?;
            check_param("cull.far", c.far as f64, 1e-3, 1e9, "in [1e-3, 1e9]")?;
            check_param("cull.margin", c.margin as f64, 0.0, 1e9, "in [0, 1e9]")?;
        }
        let dynamic = scene.dynamic_instances();
        let pose = scene.pose(config.lead);
        check_density(config.density)?;
        let area_scales = area_scales(&scene, &pose);
        let estimated = estimated_points(&scene, &area_scales, config.density);
        if estimated > config.max_points as f64 {
            return Err(SceneError::TooManyPoints {
                estimated: estimated.min(u64::MAX as f64) as u64,
                max: config.max_points,
            });
        }
        let skin_bounds = skinned_bounds(&scene, &dynamic);
        let masks = scene
            .meshes
            .iter()
            .map(|m| m.alpha.clone().map(Arc::new))
            .collect();
        // Instances are set up in parallel (points, layout, skinning);
        // each depends on its index alone, and the first error in instance
        // order is the one returned, whatever the thread count.
        let set_up = |(i, inst): (usize, &Instance)| -> Result<InstanceState, SceneError> {
            let mesh = &scene.meshes[inst.mesh];
            let seed = config.seed ^ ((i as u64) << 32);
            let deforms = scene.deforms(i);
            let mut points = generate_points_with(
                mesh,
                config.density * area_scales[i],
                seed,
                config.fill_gaps,
            )?;
            let rest = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
            // A bind-space grid covers the mesh as it is stored; a posed
            // one every place its deformation takes the points.
            let bind = deforms && config.bind_space;
            let grid_bounds = if bind {
                rest
            } else {
                skin_bounds[i].unwrap_or(rest)
            };
            // Traced where the poses take the points: their precision is
            // checked over the grid and every posed place.
            let traced_bounds = skin_bounds[i].map_or(grid_bounds, |b| {
                (b.0.min(grid_bounds.0), b.1.max(grid_bounds.1))
            });
            check_precision(
                i,
                &pose.instances[i],
                traced_bounds,
                points.radius,
                config.ao.radius,
            )?;
            let sides = if mesh.double_sided { 2.0 } else { 1.0 };
            let mut def = layout(
                i,
                grid_bounds,
                mesh.area() * sides,
                points.len(),
                points.radius.max(1e-6),
                &config.layout,
            )?;
            if bind {
                def.point_format = psao_codec::POINT_FORMAT_BIND32;
            }
            // The area estimate undercounts folded and crowded meshes'
            // cells: the table and pool hold the points' own.
            let def = fit_to_points(def, &points.positions);
            let table = GridTable::new(i as u32, def, points.len().max(1) as u32)?;
            let (vertices, vertex_normals) = scene.deformed(i, &pose);
            let (mut positions, mut normals) = (Vec::new(), Vec::new());
            if deforms {
                points.follow(
                    mesh,
                    &vertices,
                    &vertex_normals,
                    &mut positions,
                    &mut normals,
                );
            } else {
                // A rigid instance's points stay where they were made: no
                // copy of them, and no anchors (only skinning follows them).
                points.anchors = Vec::new();
            }
            let (vertices, vertex_normals) = if deforms {
                (vertices.into_owned(), vertex_normals.into_owned())
            } else {
                (Vec::new(), Vec::new())
            };
            let bounds = if deforms { bounds_of(&vertices) } else { rest };
            let blocks = if deforms {
                blocks::PointBlocks::default()
            } else {
                blocks::PointBlocks::new(&points.positions)
            };
            Ok(InstanceState {
                blocks,
                pending: if config.cull.is_some() {
                    vec![false; points.len()]
                } else {
                    Vec::new()
                },
                last_ao: vec![u8::MAX; points.len()],
                trend: match config.budget {
                    config::RayBudget::Unlimited => Vec::new(),
                    _ => vec![trend::Trend::default(); points.len()],
                },
                heat: trend::Heat::new(config.ao.radius),
                pose: trend::PoseDependence::default(),
                points,
                positions,
                normals,
                vertices,
                vertex_normals,
                scratch_vertices: Vec::new(),
                scratch_normals: Vec::new(),
                joints: pose.joints[i].clone(),
                weights: pose.weights[i].clone(),
                table,
                transform: pose.instances[i],
                transform_seq: 0,
                sent_transform: pose.instances[i],
                sent_seq: 0,
                held_steps: 0,
                bounds,
                dynamic: dynamic[i],
                bvh: None,
                buried: buried::Buried::default(),
                bind,
            })
        };
        let instances = scene
            .instances
            .par_iter()
            .enumerate()
            .map(|x| {
                let r = set_up(x);
                let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(SetupProgress {
                    stage: SetupStage::Points,
                    done: d,
                    total,
                });
                r
            })
            .collect::<Vec<_>>()
            .into_iter()
            .collect::<Result<Vec<_>, _>>()?;
        let skin_groups = skin_groups(&scene, &dynamic);
        let ray_cache = ray_cache::RayCache::new(config.ao.rays, config.ray_cache_bytes);
        let (config_rays, config_cache_bytes) = (config.ao.rays, config.ray_cache_bytes);
        let config_wait = config.max_wait;
        let loop_memory = match config.budget {
            budget::RayBudget::Unlimited => None,
            _ => scene.loop_period(loops::LOOP_LONGEST).and_then(|p| {
                let jumps = config
                    .loop_verify
                    .then(|| loops::jumps(p as f64, &scene.animations))
                    .flatten();
                loops::LoopMemory::new(p, config.loop_memory_bytes, jumps)
            }),
        };
        let mut pipeline = Pipeline {
            scene,
            backend,
            encoder: Encoder::new(config.encoder),
            config,
            instances,
            masks,
            overrides: vec![None; pose.instances.len()],
            placed: vec![false; pose.instances.len()],
            pose,
            static_layer: None,
            whole_layer: None,
            skin_groups,
            time: 0.0,
            frame: 0,
            views: Views::CameraPath,
            ray_cache,
            waiting: budget::Waiting::default(),
            moved: std::collections::VecDeque::new(),
            kept_scores: early::KeptScores::new(config_rays, config_cache_bytes),
            loop_memory,
            ray_order: early::ray_order(config_rays),
            last_early: Vec::new(),
            early_rested: Vec::new(),
            early_cost: config_rays as f64,
            last_traced: Vec::new(),
            ray_ns: 0.0,
            tail_s: 0.0,
            wait_bound: config_wait,
            envelope: reach::Envelope::default(),
            envelope_rays: Default::default(),
            envelope_masks: Vec::new(),
            stages: Vec::new(),
        };
        pipeline.stages = (0..pipeline.instances.len()).map(|_| None).collect();
        if pipeline.config.fill_buried {
            pipeline.find_buried(progress)?;
        }
        // The first trace, in batches so that progress can be told (each
        // point's AO depends on its id alone: the same in any batching).
        let total: u64 = pipeline
            .instances
            .iter()
            .map(|s| s.points.len() as u64)
            .sum();
        let tracer = pipeline.backend.is_none().then(|| pipeline.tracer(false));
        let mut traced = 0u64;
        let trace_started = std::time::Instant::now();
        progress(SetupProgress {
            stage: SetupStage::Trace,
            done: 0,
            total,
        });
        // Batches of up to TRACE_BATCH points, filled across instances in
        // order: the lists of the instances a batch touches are set, then
        // cleared for the next.
        let counts: Vec<u32> = pipeline
            .instances
            .iter()
            .map(|s| s.points.len() as u32)
            .collect();
        let mut which = vec![Vec::new(); counts.len()];
        let mut touched = Vec::new();
        let (mut i, mut start, mut room) = (0usize, 0u32, TRACE_BATCH);
        while i < counts.len() {
            let take = (counts[i] - start).min(room);
            if take > 0 {
                which[i].extend(start..start + take);
                touched.push(i);
                start += take;
                room -= take;
            }
            if start == counts[i] {
                i += 1;
                start = 0;
            }
            if room == 0 || i == counts.len() {
                if touched.is_empty() {
                    break;
                }
                pipeline.trace_and_update(tracer.as_ref(), &which, true)?;
                traced += (TRACE_BATCH - room) as u64;
                progress(SetupProgress {
                    stage: SetupStage::Trace,
                    done: traced,
                    total,
                });
                for &t in &touched {
                    which[t].clear();
                }
                touched.clear();
                room = TRACE_BATCH;
            }
        }
        let rays = total * pipeline.config.ao.rays as u64;
        if rays > 0 {
            pipeline.ray_ns = trace_started.elapsed().as_nanos() as f64 / rays as f64;
        }
        // Buried points take their donors' AO once every point is traced.
        pipeline.fill_buried(&vec![true; counts.len()], true)?;
        for s in &mut pipeline.instances {
            s.table.take_dirty();
            s.table.shrink_to_fit();
            // The first trace set every point: what it gave is held.
            let (positions, normals) = s.stored();
            let held: Vec<Option<u8>> = (0..positions.len())
                .map(|k| {
                    let w = s.table.sent(k as u32, positions[k], normals[k]).word;
                    w.is_allocated().then(|| w.fields().ao)
                })
                .collect();
            if !s.trend.is_empty() {
                // Under a budget each point's trend starts from this trace.
                for (t, q) in s.trend.iter_mut().zip(&held) {
                    if let Some(q) = *q {
                        *t = trend::Trend::seeded(q, 0);
                    }
                }
            }
            s.last_ao = held.iter().map(|q| q.unwrap_or(u8::MAX)).collect();
        }
        Ok(pipeline)
    }

    /// Seconds of scene time so far.
    pub fn time(&self) -> f32 {
        self.time as f32
    }

    /// Sets what culling (when configured) culls to from the next step
    /// on: the scene's camera path (the default), the union of viewers'
    /// frusta, or nothing. Points culled meanwhile wait and are traced when
    /// they come into a view.
    pub fn set_views(&mut self, views: Views) {
        self.views = views;
    }

    /// The settings it runs with.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The scene being streamed.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The table of instance `i`.
    pub fn table(&self, i: usize) -> Option<&GridTable> {
        self.instances.get(i).map(|s| &s.table)
    }

    /// Number of instances.
    pub fn instance_count(&self) -> usize {
        self.instances.len()
    }

    /// The points of instance `i` in its mesh's bind pose (local space).
    /// Only deforming instances keep their anchors (`PointSet::anchors` is
    /// empty for a rigid one: nothing follows its mesh).
    pub fn points(&self, i: usize) -> Option<&PointSet> {
        self.instances.get(i).map(|s| &s.points)
    }

    /// Positions and normals of instance `i`'s points now (local space;
    /// deforming instances move them): where they are traced.
    pub fn current_points(&self, i: usize) -> Option<(&[Vec3], &[Vec3])> {
        self.instances.get(i).map(InstanceState::now)
    }

    /// Positions and normals of instance `i`'s points as its table stores
    /// them and clients look them up: in the mesh's bind space for an
    /// instance of point format 1 (which never move), else as
    /// [`current_points`](Self::current_points).
    pub fn stored_points(&self, i: usize) -> Option<(&[Vec3], &[Vec3])> {
        self.instances.get(i).map(InstanceState::stored)
    }

    /// Bytes the pipeline holds for its instances (points, skinned
    /// vertices, tables, bookkeeping, kept ray scores; allocated capacity)
    /// and its BVHs' triangles: the server's memory for the scene, without what the
    /// allocator keeps aside.
    pub fn memory_bytes(&self) -> u64 {
        let bvh = |b: &Option<Arc<TriangleBvh>>| b.as_ref().map_or(0, |b| b.memory_bytes());
        self.instances
            .iter()
            .map(|s| s.memory_bytes() + bvh(&s.bvh))
            .sum::<u64>()
            + bvh(&self.static_layer)
            + bvh(&self.whole_layer)
            + self.skin_groups.iter().map(|g| bvh(&g.bvh)).sum::<u64>()
            + self.ray_cache.memory_bytes()
            + self.kept_scores.memory_bytes()
            + self.loop_memory.as_ref().map_or(0, loops::LoopMemory::memory_bytes)
            + self.waiting.memory_bytes()
            // What is known against the envelope: a slot a point, the
            // masks and their words.
            + self.envelope_rays.memory_bytes()
            + self.envelope_masks.capacity() as u64
                * std::mem::size_of::<plan::EnvelopeRays>() as u64
            + self.envelope_masks.iter().map(|m| m.heap_bytes()).sum::<u64>()
            // The boxes of the last steps, for the points planned late.
            + self.moved.iter().map(|m| m.1.heap_bytes() + 32).sum::<u64>()
    }

    /// Static points whose ray scores are kept for partial re-traces
    /// ([`PipelineConfig::ray_reuse`]).
    pub fn kept_ray_points(&self) -> usize {
        self.ray_cache.len()
    }

    /// The loop memory ([`PipelineConfig::loop_memory_bytes`]): the
    /// scene's loop period in seconds, the points remembered and the bytes
    /// they take; `None` where there is none (no budget, no loop within
    /// 20 s, a cap under one point's share or 0, or an instance was placed
    /// by hand).
    pub fn loop_memory(&self) -> Option<(f32, usize, u64)> {
        self.loop_memory
            .as_ref()
            .map(|m| (m.period(), m.len(), m.memory_bytes()))
    }

    /// The moment of the scene's loop this step poses (its time plus the
    /// lead), where there is a loop memory.
    fn loop_moment(&self) -> Option<loops::Moment> {
        let memory = self.loop_memory.as_ref()?;
        // The time the scene is posed at (each animation's time within its
        // loop is taken from it in f64).
        Some(memory.moment(self.posed_at()))
    }

    /// World transform of instance `i` now.
    pub fn transform(&self, i: usize) -> Option<Affine3A> {
        self.instances.get(i).map(|s| s.transform)
    }

    /// A tracer over the scene as it is now (what [`step`](Self::step)
    /// traces against), for reference renders and tests.
    pub fn current_tracer(&mut self) -> AoTracer {
        self.tracer(false)
    }

    /// Places dynamic instance `i` at `transform` from the next step on, in
    /// place of its animation (a scene event, such as a user moving an
    /// object). Static instances share one BVH built once and cannot be
    /// moved; a singular or non-finite transform is refused, and so is one
    /// that takes it where f32 is too coarse ([`check_precision`]).
    pub fn place_instance(&mut self, i: usize, transform: Affine3A) -> Result<(), SceneError> {
        let Some(s) = self.instances.get(i) else {
            return Err(SceneError::Element {
                element: format!("instance {i}"),
                reason: format!("the scene has {} instances", self.instances.len()),
            });
        };
        if !s.dynamic {
            return Err(SceneError::Element {
                element: format!("instance {i}"),
                reason: "is static (no animation moves it), so it cannot be placed".into(),
            });
        }
        check_transform(i, &transform, Some(s.bounds))?;
        check_precision(
            i,
            &transform,
            s.bounds,
            s.points.radius,
            self.config.ao.radius,
        )?;
        self.overrides[i] = Some(transform);
        self.placed[i] = true;
        // The instance no longer follows its animation: the scene's loop
        // is broken, and what was remembered of it says nothing now.
        self.loop_memory = None;
        Ok(())
    }

    /// Whether instance `i` can move (an animation drives it or its skin).
    pub fn is_dynamic(&self, i: usize) -> bool {
        self.instances.get(i).is_some_and(|s| s.dynamic)
    }

    /// A keyframe of the current state (for a client joining now).
    pub fn keyframe(&mut self) -> Result<EncodedFrame, SceneError> {
        let mut kf = self.encoder.keyframe();
        for s in &self.instances {
            kf.snapshot(&s.table)?;
            kf.transform(s.table.id(), s.sent_seq, &s.sent_transform.to_cols_array());
        }
        // A keyframe is always a frame (finish returns None only for empty
        // deltas).
        kf.finish()?
            .ok_or(SceneError::Encode(psao_codec::EncodeError::FrameTooLarge))
    }
}

/// For each skinned instance, the local bounds of its skinned vertices at
/// time 0 and, when it is animated, over its animations, grown by 5% of
/// their extent: room for its grid. Animations loop over their own
/// durations, so together they repeat only after a common multiple of
/// them; poses are sampled at 30 Hz over the sum of the distinct durations
/// (which covers each animation's whole loop against several phases of the
/// others), at most 60 s and [`MAX_BOUND_SAMPLES`] poses. A pose beyond the
/// sampled ones can still push points out of the grid: they are dropped and
/// counted (`TableStats::out_of_grid`), never an error.
fn skinned_bounds(scene: &Scene, dynamic: &[bool]) -> Vec<Option<(Vec3, Vec3)>> {
    let out = vec![None; scene.instances.len()];
    let skinned: Vec<usize> = (0..scene.instances.len())
        .filter(|&i| scene.deforms(i))
        .collect();
    if skinned.is_empty() {
        return out;
    }
    let mut durations: Vec<f32> = scene
        .animations
        .iter()
        .map(|a| a.duration())
        .filter(|d| *d > 0.0)
        .collect();
    durations.sort_by(f32::total_cmp);
    durations.dedup();
    let horizon = durations.iter().sum::<f32>().min(60.0);
    let samples = ((horizon * 30.0).ceil() as usize).clamp(1, MAX_BOUND_SAMPLES);
    // Poses sampled in parallel; the union of boxes (min and max) is the
    // same in any order.
    let union = |a: Option<(Vec3, Vec3)>, b: Option<(Vec3, Vec3)>| match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, b) => a.or(b),
    };
    let mut out = (0..=samples)
        .into_par_iter()
        .fold(
            || (Pose::default(), vec![None; scene.instances.len()]),
            |(mut pose, mut acc), k| {
                scene.pose_into(horizon * k as f32 / samples as f32, &mut pose);
                for &i in &skinned {
                    if k > 0 && !dynamic[i] {
                        continue;
                    }
                    let (p, _) = scene.deformed(i, &pose);
                    let b = bounds_of(&p);
                    if b.0.is_finite() && b.1.is_finite() {
                        acc[i] = union(acc[i], Some(b));
                    }
                }
                (pose, acc)
            },
        )
        .map(|(_, acc)| acc)
        .reduce(
            || vec![None; scene.instances.len()],
            |a, b| a.into_iter().zip(b).map(|(a, b)| union(a, b)).collect(),
        );
    for b in out.iter_mut().flatten() {
        let pad = (b.1 - b.0) * 0.05;
        *b = (b.0 - pad, b.1 + pad);
    }
    out
}
