//! Where a pipeline traces its AO rays when not on its own CPU tracer
//! ([`AoBackend`]).

use glam::{Affine3A, Vec3};
use psao_codec::{SentPoint, Thresholds};

use crate::error::SceneError;
use crate::trace::ao::{AoParams, AoResult, ChangedPoints};

/// Where a [`Pipeline`](crate::Pipeline) traces its AO rays instead of its
/// own CPU tracer (for instance psao-gpu's ray queries). A backend must
/// trace the rays the CPU tracer would
/// ([`AoTracer::trace_ids`](crate::AoTracer::trace_ids): same sampling,
/// estimator, radius and offset) so that both give the same points and
/// frames.
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
    /// [`AoTracer::trace_ids`](crate::AoTracer::trace_ids).
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
