//! Where a pipeline traces its AO rays when not on its own CPU tracer
//! ([`AoBackend`]).

use glam::{Affine3A, Vec3};
use psao_codec::{SentPoint, Thresholds};

use crate::error::SceneError;
use crate::trace::ao::{AoParams, AoResult, ChangedPoints};

/// One ray to cast ([`AoBackend::cast_rays`]): ray `ray` (of
/// [`AoParams::rays`]) of point `point` of a batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RayJob {
    /// The point's index in the batch.
    pub point: u32,
    /// Which of its rays ([`PointRays::ray`](crate::PointRays::ray)).
    pub ray: u32,
}

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

    /// Whether it casts single rays ([`cast_rays`](Self::cast_rays)), so
    /// that the pipeline keeps ray scores on it as on the CPU: ray reuse
    /// ([`PipelineConfig::ray_reuse`](crate::PipelineConfig::ray_reuse))
    /// and early decisions
    /// ([`PipelineConfig::early`](crate::PipelineConfig::early)). False
    /// by default: every point it traces costs all its rays.
    fn casts_rays(&self) -> bool {
        false
    }

    /// The score of each ray of `jobs` (in its order): ray `ray` of point
    /// `point` (an index into `ids`, `points` and `normals`), as
    /// [`PointRays::score`](crate::PointRays::score) gives it: `min(t,
    /// R) / R` for a closest-hit ray, 1 or 0 for a Laine-Karras one, 1
    /// for a point with nothing to trace from. The point's AO is
    /// [`ao_of_scores`](crate::ao_of_scores) of its rays' scores, which
    /// must be what [`trace_ids`](Self::trace_ids) gives, bit for bit. A
    /// job naming a point or ray out of range is an error. Only called
    /// where [`casts_rays`](Self::casts_rays) says so; the default says
    /// it is not supported.
    fn cast_rays(
        &mut self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        jobs: &[RayJob],
        params: &AoParams,
    ) -> Result<Vec<f32>, SceneError> {
        let _ = (ids, points, normals, jobs, params);
        Err(SceneError::Backend {
            backend: self.name(),
            reason: "it does not cast single rays".into(),
        })
    }

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
