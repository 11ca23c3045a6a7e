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
#[derive(Debug)]
pub struct GpuBackend {
    ctx: GpuContext,
    scene: Scene,
    accel: GpuScene,
    ao: GpuAo,
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
        })
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

    /// It does: the pipeline keeps ray scores on the GPU as on the CPU.
    fn casts_rays(&self) -> bool {
        true
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
