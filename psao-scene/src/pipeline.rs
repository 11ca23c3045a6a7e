//! The server frame pipeline (paper 3.3): animate -> carry skinned points
//! along (in instance-local space) -> choose the points to re-trace ->
//! trace -> compare with what clients hold (thresholds) -> GridTable ->
//! Encoder.
//!
//! Skipping what the scene does not need is part of the design:
//! - a rigidly moving instance sends only its transform; its own points are
//!   re-traced (their surroundings changed) but sent only if their AO moved
//!   past the threshold;
//! - a skinned instance re-traces its points when its pose changes, and
//!   sends those whose position, normal or AO passed the thresholds;
//! - a static instance is re-traced only where its points lie within reach
//!   (the AO radius) of a moving instance's swept bounds;
//! - with per-viewer culling, points outside the viewer's extended frustum
//!   wait until they come into view;
//! - static geometry sits in a BVH built once; only the moving part is
//!   rebuilt;
//! - a frame with nothing to say is not sent.

use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Affine3A, Vec3};
use psao_codec::{EncodedFrame, Encoder, EncoderConfig, GridTable, SentPoint, Thresholds};

use crate::alpha::AlphaMask;
use crate::ao::{
    AoParams, AoResult, AoTracer, ChangedPoints, Geometry, Layer, TriangleBvh, ray_offset,
};
use crate::camera::Frustum;
use crate::error::{SceneError, check_param};
use crate::layout::{LayoutParams, layout};
use crate::points::{PointSet, generate_points};
use crate::pose::{Pose, normal_matrix};
use crate::precision::check_precision;
use crate::scene::{Scene, check_transform, transformed_bounds};

/// Per-viewer culling: the server traces only points near what is seen,
/// by default the view of the scene's camera path, or the union of the
/// views given with [`Pipeline::set_views`] (a server's clients).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewerCull {
    /// Width over height of the viewer's image.
    pub aspect: f32,
    /// Far plane distance.
    pub far: f32,
    /// How far beyond the frustum (on top of the AO radius) points still
    /// count as in view: room for the camera to move before the next frame.
    pub margin: f32,
}

impl ViewerCull {
    /// The near plane distance culling uses: 5 cm, or half the far plane
    /// when that is nearer.
    pub fn near(&self) -> f32 {
        0.05f32.min(self.far * 0.5)
    }
}

impl Default for ViewerCull {
    fn default() -> Self {
        ViewerCull {
            aspect: 16.0 / 9.0,
            far: 100.0,
            margin: 0.5,
        }
    }
}

/// What culling culls to (with [`PipelineConfig::cull`] set).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Views {
    /// The scene's camera path at the pipeline's time (nothing is culled
    /// when the scene has none).
    #[default]
    CameraPath,
    /// The union of these frusta (a server's viewers). An empty list: no
    /// one looks, every point waits.
    Frusta(Vec<Frustum>),
    /// Everything: nothing is culled (a client that does not say what it
    /// sees is connected).
    All,
}

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
    /// Keep static geometry in a BVH built once and rebuild only the
    /// moving part (true), or rebuild one BVH over everything whenever
    /// something moves (false: the baseline).
    pub split_bvh: bool,
    /// Trace only near one viewer's frustum (needs a scene camera path);
    /// `None` when one stream serves many viewers.
    pub cull: Option<ViewerCull>,
}

impl PipelineConfig {
    /// The defaults with `density` points spawned per square metre and
    /// `rays` AO rays per point (the two settings most callers choose).
    pub fn with_density_and_rays(density: f32, rays: u32) -> PipelineConfig {
        PipelineConfig {
            density,
            ao: AoParams {
                rays,
                ..AoParams::default()
            },
            ..PipelineConfig::default()
        }
    }
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
            split_bvh: true,
            cull: None,
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
    /// Points that needed re-tracing but were out of the viewer's view
    /// (they wait until they come into view).
    pub culled: u64,
    /// Rays cast.
    pub rays: u64,
    /// Points whose change passed the thresholds (set in their table).
    pub updated: u64,
    /// Transforms sent.
    pub transforms: u32,
    /// Skinned instances whose pose changed.
    pub deformed: u32,
    /// Instances whose new pose was degenerate (a singular or non-finite
    /// transform, or skinned vertices that overflow) and that kept their
    /// last valid pose instead.
    pub held: u32,
    /// Bytes of the frame sent (0 when none was).
    pub bytes: u64,
    /// Time to evaluate animations and skin meshes and points.
    pub t_animate: Duration,
    /// Time to choose the points to re-trace.
    pub t_select: Duration,
    /// Time to build BVHs.
    pub t_bvh: Duration,
    /// Time to trace.
    pub t_trace: Duration,
    /// Time to update tables and encode.
    pub t_encode: Duration,
}

impl FrameReport {
    /// Adds `other`'s counts and times to this one (`points` is kept as the
    /// larger of the two).
    pub fn accumulate(&mut self, other: &FrameReport) {
        self.points = self.points.max(other.points);
        self.traced += other.traced;
        self.culled += other.culled;
        self.rays += other.rays;
        self.updated += other.updated;
        self.transforms += other.transforms;
        self.deformed += other.deformed;
        self.held += other.held;
        self.bytes += other.bytes;
        self.t_animate += other.t_animate;
        self.t_select += other.t_select;
        self.t_bvh += other.t_bvh;
        self.t_trace += other.t_trace;
        self.t_encode += other.t_encode;
    }

    /// Server time of the frame, all stages.
    pub fn total_time(&self) -> Duration {
        self.t_animate + self.t_select + self.t_bvh + self.t_trace + self.t_encode
    }
}

struct InstanceState {
    /// Points in the mesh's bind pose.
    points: PointSet,
    /// Points now (instance-local; skinned instances move them).
    positions: Vec<Vec3>,
    /// Point normals now.
    normals: Vec<Vec3>,
    /// Skinned vertex positions and normals now (empty: the mesh's own).
    vertices: Vec<Vec3>,
    vertex_normals: Vec<Vec3>,
    /// Room to skin into before the new pose is known to be sound.
    scratch_vertices: Vec<Vec3>,
    scratch_normals: Vec<Vec3>,
    /// Joint matrices of the current pose (skinned instances).
    joints: Vec<Affine3A>,
    table: GridTable,
    transform: Affine3A,
    transform_seq: u32,
    /// Local bounds of the mesh as it is now.
    bounds: (Vec3, Vec3),
    /// Whether it can move or deform.
    dynamic: bool,
    /// Points waiting to be traced until they come into view.
    pending: Vec<bool>,
    /// Its own BVH in local space (dynamic instances, split BVH): moved by
    /// its transform, refitted when it deforms.
    bvh: Option<Arc<TriangleBvh>>,
}

/// Where a [`Pipeline`] traces its AO rays instead of its own CPU tracer
/// (for instance psao-gpu's ray queries). A backend must trace the rays
/// the CPU tracer would ([`AoTracer::trace_ids`]: same sampling, estimator,
/// radius and offset) so that both give the same points and frames.
pub trait AoBackend: Send {
    /// A short name for reports, such as `gpu: ADAPTER`.
    fn name(&self) -> String;

    /// Places the scene as it is now before a trace: per instance its
    /// local-to-world transform and, for an instance whose mesh deforms
    /// (skinning), its current local vertex positions (`None`: the mesh's
    /// own positions).
    fn place(
        &mut self,
        transforms: &[Affine3A],
        vertices: &[Option<&[Vec3]>],
    ) -> Result<(), SceneError>;

    /// AO at world points with unit normals and stable ids, as
    /// [`AoTracer::trace_ids`].
    fn trace_ids(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        params: &AoParams,
    ) -> Result<AoResult, SceneError>;

    /// Traces as [`AoBackend::trace_ids`] and keeps the points worth
    /// sending against what clients hold (`sent`, one record per point):
    /// the same points as [`ChangedPoints::compare`] on the traced AO. The
    /// default does exactly that on the host; a backend may compare where
    /// it traced and hand back only the changed points.
    fn trace_changed(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        sent: &[SentPoint],
        params: &AoParams,
        thresholds: &Thresholds,
    ) -> Result<ChangedPoints, SceneError> {
        let result = self.trace_ids(ids, points, normals, params)?;
        ChangedPoints::compare(&result, sent, thresholds)
    }
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
    static_layer: Option<Arc<TriangleBvh>>,
    whole_layer: Option<Arc<TriangleBvh>>,
    time: f64,
    frame: u64,
    /// What culling culls to.
    views: Views,
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

fn bounds_of(points: &[Vec3]) -> (Vec3, Vec3) {
    crate::scene::bounds_of(points).unwrap_or((Vec3::ZERO, Vec3::ZERO))
}

/// Most poses sampled to find a skinned instance's bounds over its
/// animation.
const MAX_BOUND_SAMPLES: usize = 1800;

impl Pipeline {
    /// Generates points for every instance, lays out their grids and traces
    /// every point once (the state the first keyframe carries). Refuses a
    /// scene that f32 cannot place finely enough for its AO radius and
    /// point spacing ([`check_precision`], in the pose at time 0).
    pub fn new(scene: Scene, config: PipelineConfig) -> Result<Pipeline, SceneError> {
        Pipeline::build(scene, config, None)
    }

    /// As [`new`](Self::new), with AO traced by `backend` (from the first
    /// trace on) instead of the CPU tracer.
    pub fn with_backend(
        scene: Scene,
        config: PipelineConfig,
        backend: Box<dyn AoBackend>,
    ) -> Result<Pipeline, SceneError> {
        Pipeline::build(scene, config, Some(backend))
    }

    /// The backend's name, or "cpu".
    pub fn backend_name(&self) -> String {
        self.backend.as_ref().map_or("cpu".into(), |b| b.name())
    }

    fn build(
        scene: Scene,
        config: PipelineConfig,
        backend: Option<Box<dyn AoBackend>>,
    ) -> Result<Pipeline, SceneError> {
        scene.validate()?;
        config.ao.validate()?;
        if let Some(c) = &config.cull {
            check_param("cull.aspect", c.aspect as f64, 1e-3, 1e3, "in [1e-3, 1e3]")?;
            check_param("cull.far", c.far as f64, 1e-3, 1e9, "in [1e-3, 1e9]")?;
            check_param("cull.margin", c.margin as f64, 0.0, 1e9, "in [0, 1e9]")?;
        }
        let dynamic = scene.dynamic_instances();
        let pose = scene.pose(0.0);
        let skin_bounds = skinned_bounds(&scene, &dynamic);
        let masks = scene
            .meshes
            .iter()
            .map(|m| m.alpha.clone().map(Arc::new))
            .collect();
        let mut instances = Vec::with_capacity(scene.instances.len());
        for (i, inst) in scene.instances.iter().enumerate() {
            let mesh = &scene.meshes[inst.mesh];
            let seed = config.seed ^ ((i as u64) << 32);
            let points = generate_points(mesh, config.density, seed)?;
            let rest = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
            let grid_bounds = skin_bounds[i].unwrap_or(rest);
            check_precision(
                i,
                &pose.instances[i],
                grid_bounds,
                points.radius,
                config.ao.radius,
            )?;
            let sides = if mesh.double_sided { 2.0 } else { 1.0 };
            let def = layout(
                i,
                grid_bounds,
                mesh.area() * sides,
                points.len(),
                points.radius.max(1e-6),
                &config.layout,
            )?;
            let table = GridTable::new(i as u32, def, points.len().max(1) as u32)?;
            let (vertices, vertex_normals) = scene.skinned(i, &pose);
            let skinned = inst.skin.is_some() && mesh.skin.is_some();
            let (mut positions, mut normals) = (Vec::new(), Vec::new());
            if skinned {
                points.follow(
                    mesh,
                    &vertices,
                    &vertex_normals,
                    &mut positions,
                    &mut normals,
                );
            } else {
                positions.clone_from(&points.positions);
                normals.clone_from(&points.normals);
            }
            let (vertices, vertex_normals) = if skinned {
                (vertices.into_owned(), vertex_normals.into_owned())
            } else {
                (Vec::new(), Vec::new())
            };
            let bounds = if skinned { bounds_of(&vertices) } else { rest };
            instances.push(InstanceState {
                pending: if config.cull.is_some() {
                    vec![false; points.len()]
                } else {
                    Vec::new()
                },
                points,
                positions,
                normals,
                vertices,
                vertex_normals,
                scratch_vertices: Vec::new(),
                scratch_normals: Vec::new(),
                joints: pose.joints[i].clone(),
                table,
                transform: pose.instances[i],
                transform_seq: 0,
                bounds,
                dynamic: dynamic[i],
                bvh: None,
            });
        }
        let mut pipeline = Pipeline {
            scene,
            backend,
            encoder: Encoder::new(config.encoder),
            config,
            instances,
            masks,
            overrides: vec![None; pose.instances.len()],
            pose,
            static_layer: None,
            whole_layer: None,
            time: 0.0,
            frame: 0,
            views: Views::CameraPath,
        };
        let all: Vec<Vec<u32>> = pipeline
            .instances
            .iter()
            .map(|s| (0..s.points.len() as u32).collect())
            .collect();
        let tracer = pipeline.backend.is_none().then(|| pipeline.tracer(false));
        pipeline.trace_and_update(tracer.as_ref(), &all, true)?;
        for s in &mut pipeline.instances {
            s.table.take_dirty();
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
    pub fn points(&self, i: usize) -> Option<&PointSet> {
        self.instances.get(i).map(|s| &s.points)
    }

    /// Positions and normals of instance `i`'s points now (local space;
    /// skinned instances move them).
    pub fn current_points(&self, i: usize) -> Option<(&[Vec3], &[Vec3])> {
        self.instances
            .get(i)
            .map(|s| (s.positions.as_slice(), s.normals.as_slice()))
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
            kf.transform(s.table.id(), s.transform_seq, &s.transform.to_cols_array());
        }
        // A keyframe is always a frame (finish returns None only for empty
        // deltas).
        kf.finish()?
            .ok_or(SceneError::Encode(psao_codec::EncodeError::FrameTooLarge))
    }

    /// Instance `i`'s triangles (with alpha masks) as they are now, in its
    /// local space, or in world space with `world`.
    fn instance_geometry(&self, i: usize, world: bool, g: &mut Geometry) {
        let (s, inst) = (&self.instances[i], &self.scene.instances[i]);
        let m = &self.scene.meshes[inst.mesh];
        let verts = if s.vertices.is_empty() {
            &m.positions
        } else {
            &s.vertices
        };
        let mask = &self.masks[inst.mesh];
        for t in 0..m.triangle_count() {
            let idx = &m.indices[3 * t..3 * t + 3];
            let corner = |k: usize| {
                let p = verts[idx[k] as usize];
                if world {
                    s.transform.transform_point3(p)
                } else {
                    p
                }
            };
            g.triangles.push([corner(0), corner(1), corner(2)]);
            g.masks
                .push(mask.as_ref().map(|m| (m.clone(), [idx[0], idx[1], idx[2]])));
        }
    }

    /// World-space geometry of the instances `pick` selects.
    fn world_geometry(&self, pick: impl Fn(&InstanceState) -> bool) -> Geometry {
        let mut g = Geometry::default();
        for i in 0..self.instances.len() {
            if pick(&self.instances[i]) {
                self.instance_geometry(i, true, &mut g);
            }
        }
        g
    }

    /// The tracer for the scene now. With a split BVH, static geometry
    /// sits in one world-space BVH built once, and each dynamic instance in
    /// its own local-space BVH, placed by its transform (rigid motion
    /// rebuilds nothing) and refitted when it deforms (see
    /// [`refit_deformed`](Self::refit_deformed)). Unsplit, one world-space
    /// BVH over everything is rebuilt whenever `changed`.
    fn tracer(&mut self, changed: bool) -> AoTracer {
        if !self.config.split_bvh {
            if changed || self.whole_layer.is_none() {
                self.whole_layer = Some(Arc::new(TriangleBvh::new(self.world_geometry(|_| true))));
            }
            return AoTracer::from_layers(
                self.whole_layer.iter().cloned().map(Layer::world).collect(),
            );
        }
        if self.static_layer.is_none() {
            self.static_layer = Some(Arc::new(TriangleBvh::new(
                self.world_geometry(|s| !s.dynamic),
            )));
        }
        for i in 0..self.instances.len() {
            if self.instances[i].dynamic && self.instances[i].bvh.is_none() {
                let mut g = Geometry::default();
                self.instance_geometry(i, false, &mut g);
                let bvh = if self.instances[i].vertices.is_empty() {
                    TriangleBvh::new(g)
                } else {
                    TriangleBvh::refittable(g)
                };
                self.instances[i].bvh = Some(Arc::new(bvh));
            }
        }
        let mut layers: Vec<Layer> = self
            .static_layer
            .iter()
            .cloned()
            .map(Layer::world)
            .collect();
        layers.extend(
            self.instances
                .iter()
                .filter_map(|s| s.bvh.clone().map(|b| Layer::placed(b, s.transform))),
        );
        AoTracer::from_layers(layers)
    }

    /// Refits the BVH of every instance in `deformed` to its mesh as it is
    /// now.
    fn refit_deformed(&mut self, deformed: &[usize]) {
        for &i in deformed {
            if self.instances[i].bvh.is_none() {
                continue;
            }
            let mut g = Geometry::default();
            self.instance_geometry(i, false, &mut g);
            if let Some(bvh) = &mut self.instances[i].bvh {
                Arc::make_mut(bvh).refit(&g.triangles);
            }
        }
    }

    /// Traces the listed points of each instance (world space) and sets the
    /// ones past the thresholds (all of them with `force`). Returns (traced,
    /// rays, updated).
    fn trace_and_update(
        &mut self,
        tracer: Option<&AoTracer>,
        which: &[Vec<u32>],
        force: bool,
    ) -> Result<(u64, u64, u64), SceneError> {
        let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
        // (instance, point) of each traced point, and what clients hold.
        let (mut owner, mut sent) = (Vec::new(), Vec::new());
        // Cells are numbered across instances: instance i's start after
        // the pools of those before it.
        let (mut base, mut cell_base) = (0u32, 0u32);
        for (i, (s, list)) in self.instances.iter().zip(which).enumerate() {
            let nm = normal_matrix(&s.transform);
            for &k in list {
                let (p, n) = (s.positions[k as usize], s.normals[k as usize]);
                ids.push(base + k);
                pts.push(s.transform.transform_point3(p));
                nrm.push((nm * n).normalize_or_zero());
                owner.push((i, k));
                sent.push(if force {
                    SentPoint::not_held(Vec3::ZERO)
                } else {
                    let mut held = s.table.sent(k, p, n);
                    held.cell = held.cell.saturating_add(cell_base);
                    held
                });
            }
            base += s.points.len() as u32;
            cell_base = cell_base.saturating_add(s.table.def().cell_pool);
        }
        let (ao, th) = (self.config.ao, self.config.thresholds);
        let result = match (&mut self.backend, tracer) {
            (Some(backend), _) => {
                let transforms: Vec<Affine3A> =
                    self.instances.iter().map(|s| s.transform).collect();
                let vertices: Vec<Option<&[Vec3]>> = self
                    .instances
                    .iter()
                    .map(|s| (!s.vertices.is_empty()).then_some(s.vertices.as_slice()))
                    .collect();
                backend.place(&transforms, &vertices)?;
                if force {
                    // Everything is sent: nothing to compare.
                    let r = backend.trace_ids(&ids, &pts, &nrm, &ao)?;
                    ChangedPoints::compare(&r, &sent, &th)?
                } else {
                    backend.trace_changed(&ids, &pts, &nrm, &sent, &ao, &th)?
                }
            }
            (None, Some(tracer)) => {
                ChangedPoints::compare(&tracer.trace_ids(&ids, &pts, &nrm, &ao)?, &sent, &th)?
            }
            (None, None) => ChangedPoints::compare(
                &self.tracer(false).trace_ids(&ids, &pts, &nrm, &ao)?,
                &sent,
                &th,
            )?,
        };
        if result.changed.len() != result.ao.len() {
            return Err(SceneError::Backend {
                backend: self.backend_name(),
                reason: format!(
                    "{} changed points but {} AO values",
                    result.changed.len(),
                    result.ao.len()
                ),
            });
        }
        for (&at, &value) in result.changed.iter().zip(&result.ao) {
            let Some(&(i, k)) = owner.get(at as usize) else {
                return Err(SceneError::Backend {
                    backend: self.backend_name(),
                    reason: format!("changed point {at} of a batch of {}", owner.len()),
                });
            };
            let s = &mut self.instances[i];
            let (p, n) = (s.positions[k as usize], s.normals[k as usize]);
            s.table.set_point(k, p, n, value)?;
        }
        Ok((ids.len() as u64, result.rays, result.changed.len() as u64))
    }

    /// Advances the scene by `dt` seconds and produces the frame clients
    /// need, if any. Scene time is kept in f64, so a run is the same for
    /// the same sequence of steps.
    pub fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, FrameReport), SceneError> {
        check_param("dt", dt as f64, 0.0, 1e6, "finite, in [0, 1e6] seconds")?;
        let t0 = Instant::now();
        self.time += dt as f64;
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
        // Animate; remember where motion happened (swept bounds).
        self.scene.pose_into(self.time as f32, &mut self.pose);
        let mut report = FrameReport {
            points: self.instances.iter().map(|s| s.points.len() as u64).sum(),
            ..FrameReport::default()
        };
        let mut moved = vec![false; self.instances.len()];
        let mut changed = vec![false; self.instances.len()];
        let mut deformed_list = Vec::new();
        let mut swept = Vec::new();
        for (i, s) in self.instances.iter_mut().enumerate() {
            if !s.dynamic {
                continue;
            }
            let next = self.overrides[i].unwrap_or(self.pose.instances[i]);
            let joints = &self.pose.joints[i];
            let deformed = !s.vertices.is_empty() && *joints != s.joints;
            if next == s.transform && !deformed {
                continue;
            }
            // Work out the new state before changing anything: a degenerate
            // pose (a singular or non-finite transform, say an object
            // scaled to zero to hide it, or skinned vertices that overflow)
            // keeps the instance where it was.
            let inst = &self.scene.instances[i];
            let mesh = &self.scene.meshes[inst.mesh];
            let mut bounds = s.bounds;
            if deformed && let Some(w) = &mesh.skin {
                w.skin(
                    &mesh.positions,
                    &mesh.normals,
                    joints,
                    &mut s.scratch_vertices,
                    &mut s.scratch_normals,
                );
                bounds = bounds_of(&s.scratch_vertices);
            }
            let after = transformed_bounds(&next, bounds);
            if check_transform(i, &next, Some(bounds)).is_err()
                || !after.0.is_finite()
                || !after.1.is_finite()
            {
                report.held += 1;
                continue;
            }
            let before = transformed_bounds(&s.transform, s.bounds);
            if deformed {
                std::mem::swap(&mut s.vertices, &mut s.scratch_vertices);
                std::mem::swap(&mut s.vertex_normals, &mut s.scratch_normals);
                s.points.follow(
                    mesh,
                    &s.vertices,
                    &s.vertex_normals,
                    &mut s.positions,
                    &mut s.normals,
                );
                s.bounds = bounds;
                s.joints.clone_from(joints);
                report.deformed += 1;
                deformed_list.push(i);
            }
            swept.push(grow((before.0.min(after.0), before.1.max(after.1))));
            if next != s.transform {
                s.transform = next;
                s.transform_seq = s.transform_seq.wrapping_add(1);
                moved[i] = true;
            }
            changed[i] = true;
        }
        report.t_animate = t0.elapsed();
        let t1 = Instant::now();
        // Choose the points to re-trace.
        let mut which: Vec<Vec<u32>> = vec![Vec::new(); self.instances.len()];
        if !self.config.skip {
            for (w, s) in which.iter_mut().zip(&self.instances) {
                *w = (0..s.points.len() as u32).collect();
            }
        } else if !swept.is_empty() {
            for (i, s) in self.instances.iter().enumerate() {
                if changed[i] {
                    which[i] = (0..s.points.len() as u32).collect();
                    continue;
                }
                let wb = transformed_bounds(&s.transform, s.bounds);
                if !swept.iter().any(|&b| overlaps(b, grow(wb))) {
                    continue;
                }
                which[i] = (0..s.points.len() as u32)
                    .filter(|&k| {
                        let p = s.transform.transform_point3(s.positions[k as usize]);
                        swept
                            .iter()
                            .any(|b| p.cmpge(b.0).all() && p.cmple(b.1).all())
                    })
                    .collect();
            }
        }
        if let Some(cull) = self.config.cull {
            report.culled = self.cull(&cull, &mut which);
        }
        report.t_select = t1.elapsed();
        let anything = which.iter().any(|w| !w.is_empty());
        let t2 = Instant::now();
        if self.config.split_bvh {
            self.refit_deformed(&deformed_list);
        } else if changed.contains(&true) {
            // Rebuilt the next time something is traced.
            self.whole_layer = None;
        }
        let tracer = (anything && self.backend.is_none()).then(|| self.tracer(false));
        report.t_bvh = t2.elapsed();
        let t3 = Instant::now();
        if anything {
            let (traced, rays, updated) = self.trace_and_update(tracer.as_ref(), &which, false)?;
            report.traced = traced;
            report.rays = rays;
            report.updated = updated;
        }
        report.t_trace = t3.elapsed();
        let t4 = Instant::now();
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
        report.t_encode = t4.elapsed();
        Ok((frame, report))
    }

    /// Keeps in `which` only the points near the viewer's frustum; the
    /// others become pending, and pending points now in view join `which`.
    /// Returns how many points wait.
    fn cull(&mut self, cull: &ViewerCull, which: &mut [Vec<u32>]) -> u64 {
        let frusta: Vec<Frustum> = match &self.views {
            Views::All => Vec::new(),
            Views::Frusta(f) => f.clone(),
            Views::CameraPath => match &self.scene.camera {
                Some(path) => {
                    vec![
                        path.at(self.time as f32)
                            .frustum(cull.aspect, cull.near(), cull.far),
                    ]
                }
                None => Vec::new(),
            },
        };
        let everything = matches!(self.views, Views::All)
            || (self.views == Views::CameraPath && self.scene.camera.is_none());
        let reach = cull.margin + self.config.ao.radius;
        let mut waiting = 0u64;
        for (s, w) in self.instances.iter_mut().zip(which.iter_mut()) {
            for &k in w.iter() {
                s.pending[k as usize] = true;
            }
            w.clear();
            for (k, pending) in s.pending.iter_mut().enumerate() {
                if !*pending {
                    continue;
                }
                let p = s.transform.transform_point3(s.positions[k]);
                if everything || frusta.iter().any(|f| f.touches_sphere(p, reach)) {
                    *pending = false;
                    w.push(k as u32);
                } else {
                    waiting += 1;
                }
            }
        }
        waiting
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
    let mut out = vec![None; scene.instances.len()];
    let skinned: Vec<usize> = (0..scene.instances.len())
        .filter(|&i| {
            scene.instances[i].skin.is_some()
                && scene.meshes[scene.instances[i].mesh].skin.is_some()
        })
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
    let mut pose = Pose::default();
    for k in 0..=samples {
        scene.pose_into(horizon * k as f32 / samples as f32, &mut pose);
        for &i in &skinned {
            if k > 0 && !dynamic[i] {
                continue;
            }
            let (p, _) = scene.skinned(i, &pose);
            let b = bounds_of(&p);
            if !b.0.is_finite() || !b.1.is_finite() {
                continue;
            }
            out[i] = Some(match out[i] {
                Some((lo, hi)) => (b.0.min(lo), b.1.max(hi)),
                None => b,
            });
        }
    }
    for b in out.iter_mut().flatten() {
        let pad = (b.1 - b.0) * 0.05;
        *b = (b.0 - pad, b.1 + pad);
    }
    out
}
