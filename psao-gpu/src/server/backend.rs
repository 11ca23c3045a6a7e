//! The GPU as a [`Pipeline`](psao_scene::Pipeline)'s AO backend: the
//! pipeline animates and skins, the GPU places its acceleration structures
//! the same way and traces the rays.

use glam::{Affine3A, Vec3};
use psao_codec::{SentPoint, Thresholds};
use psao_scene::{AoBackend, AoParams, AoResult, ChangedPoints, RayJob, Scene, SceneError};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::server::accel::GpuScene;
use crate::server::ao::GpuAo;

/// Ray-query AO for a server pipeline ([`psao_scene::Pipeline::with_backend`]).
///
/// It traces whole points by default: every ray of each point the
/// pipeline traces, in the AO pass, compared with what clients hold on
/// the GPU (motion's reach still leaves out the points none of whose rays
/// it can reach). With [`with_single_rays`](Self::with_single_rays) it
/// casts the rays the pipeline asks for instead
/// ([`AoBackend::cast_rays`]), so that ray scores are kept as on the CPU
/// tracer: ray reuse and early decisions then follow the CPU's rules, and
/// the budget prices points alike on both. On lavapipe the rays that
/// remain to cast cost about twice as much each, so whole points held
/// more PSNR under an automatic budget there (BENCHMARKS.md, "The ray
/// budget on the GPU backend").
#[derive(Debug)]
pub struct GpuBackend {
    ctx: GpuContext,
    scene: Scene,
    accel: GpuScene,
    ao: GpuAo,
    single_rays: bool,
}

impl GpuBackend {
    /// Opens the device and uploads `scene` (the one the pipeline streams).
    pub fn new(scene: &Scene) -> Result<GpuBackend, GpuError> {
        let ctx = GpuContext::new()?;
        let accel = GpuScene::new(&ctx, scene)?;
        let ao = GpuAo::new(&ctx)?;
        Ok(GpuBackend {
            ctx,
            scene: scene.clone(),
            accel,
            ao,
            single_rays: false,
        })
    }

    /// Casts single rays (`true`: ray scores kept as on the CPU, with ray
    /// reuse and early decisions where the pipeline's configuration asks
    /// for them) or traces whole points (`false`, the default).
    pub fn with_single_rays(mut self, on: bool) -> GpuBackend {
        self.single_rays = on;
        self
    }

    fn fail(&self, e: GpuError) -> SceneError {
        SceneError::Backend {
            backend: self.name(),
            reason: e.to_string(),
        }
    }
}

impl AoBackend for GpuBackend {
    fn name(&self) -> String {
        format!("gpu: {}", self.ctx.describe())
    }

    fn place(
        &mut self,
        transforms: &[Affine3A],
        vertices: &[Option<&[Vec3]>],
    ) -> Result<(), SceneError> {
        self.accel
            .place(&self.ctx, &self.scene, transforms, vertices)
            .map_err(|e| self.fail(e))
    }

    fn trace_ids(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        params: &AoParams,
    ) -> Result<AoResult, SceneError> {
        self.ao
            .trace_ids(&self.ctx, &self.accel, ids, points, normals, params)
            .map_err(|e| self.fail(e))
    }

    /// Where [`with_single_rays`](GpuBackend::with_single_rays) asked
    /// for it: the pipeline then keeps ray scores on the GPU as on the
    /// CPU.
    fn casts_rays(&self) -> bool {
        self.single_rays
    }

    /// Casts them on the GPU ([`GpuAo::cast_rays`]).
    fn cast_rays(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        jobs: &[RayJob],
        params: &AoParams,
    ) -> Result<Vec<f32>, SceneError> {
        self.ao
            .cast_rays(&self.ctx, &self.accel, ids, points, normals, jobs, params)
            .map_err(|e| self.fail(e))
    }

    /// Compares on the GPU ([`GpuAo::trace_changed`]): only the changed
    /// points cross back.
    fn trace_changed(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        sent: &[SentPoint],
        params: &AoParams,
        thresholds: &Thresholds,
    ) -> Result<ChangedPoints, SceneError> {
        self.ao
            .trace_changed(
                &self.ctx,
                &self.accel,
                ids,
                points,
                normals,
                sent,
                params,
                thresholds,
            )
            .map_err(|e| self.fail(e))
    }
}
