//! A rigid mover traced whole over several steps at one pose (a *stage*).
//!
//! Under [`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)
//! a moving rigid part's points are traced together, and clients hold the
//! part's transform at the pose they were traced in. A part whose points
//! cost more than a step's budget was held until it fit, or for
//! [`max_wait`](super::config::PipelineConfig::max_wait) steps and then
//! traced in one step several periods long. On the CPU a held part is
//! now traced in slices instead. The step that holds it plans the stage:
//! how many of the part's points each step traces (enough to end before
//! the first of them comes due, and at least half a budget's worth), so
//! in which step it ends, and the scene with the part where its
//! animation takes it by that step (an [`AoTracer`] whose layers are
//! shared with the step's). Each step traces a slice against that
//! snapshot; the step the stage ends in sets them all, and clients get
//! the snapshot's transform with them. The part's AO arrives whole and
//! consistent, and where the animation is known ahead, with the pose the
//! part has when it arrives.

use glam::{Affine3A, Vec3};
use rayon::prelude::*;

use crate::model::pose::normal_matrix;
use crate::trace::ao::{AoParams, AoTracer};

/// One part's stage: the scene posed for it, and the points traced so
/// far.
pub(super) struct Stage {
    /// The scene with the part posed where it is to be in the stage's
    /// last step (layers shared).
    tracer: AoTracer,
    /// The part's transform in that scene: what clients get with the
    /// points.
    pub transform: Affine3A,
    /// The points to trace, ascending.
    todo: Vec<u32>,
    /// How many of `todo` are traced; their AO, in `todo`'s order.
    ao: Vec<f32>,
    /// Points a step traces.
    pub slice: usize,
    /// The step (the pipeline's frame number) the stage ends in.
    pub ends_at: u64,
}

impl Stage {
    /// A stage of `todo` (ascending, deduplicated) against `tracer`, the
    /// part at `transform` there; `slice` points a step, ending in step
    /// `ends_at`.
    pub fn new(
        (tracer, transform): (AoTracer, Affine3A),
        todo: Vec<u32>,
        slice: usize,
        ends_at: u64,
    ) -> Stage {
        Stage {
            tracer,
            transform,
            ao: Vec::with_capacity(todo.len()),
            todo,
            slice: slice.max(1),
            ends_at,
        }
    }

    /// Whether, ending in step `step` with the part at `now`, it ends as
    /// planned: in its step, or earlier (made to) with the part already
    /// where the stage traced it. Else its AO is of a pose the part has
    /// not reached yet, and the part is traced now instead.
    pub fn ends_as_planned(&self, step: u64, now: &Affine3A) -> bool {
        step >= self.ends_at || self.transform == *now
    }

    /// Rays its untraced points cost, at `rays` each.
    pub fn left(&self, rays: u32) -> u64 {
        (self.todo.len() - self.ao.len()) as u64 * u64::from(rays)
    }

    /// The AO traced for point `k`, if it is.
    pub fn traced(&self, k: u32) -> Option<f32> {
        let at = self.todo.binary_search(&k).ok()?;
        self.ao.get(at).copied()
    }

    /// Traces the next untraced points, as many as `rays` rays pay for
    /// (whole points), at the snapshot's pose: `local` and `normals` are
    /// the part's points in its own space, `base` the id of its point 0.
    /// Returns the rays cast.
    pub fn trace_next(
        &mut self,
        rays: u64,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> u64 {
        let per = u64::from(ao.rays.max(1));
        let n = usize::try_from(rays / per).unwrap_or(usize::MAX);
        let from = self.ao.len();
        let to = self.todo.len().min(from.saturating_add(n));
        self.trace_range(from..to, (local, normals), base, ao)
    }

    /// Traces every point left (the last slice). Returns the rays cast.
    pub fn trace_rest(&mut self, points: (&[Vec3], &[Vec3]), base: u32, ao: &AoParams) -> u64 {
        let range = self.ao.len()..self.todo.len();
        self.trace_range(range, points, base, ao)
    }

    /// The AO of point `k` traced now against the snapshot (a point of the
    /// part that joined after the stage began), and the rays cast.
    pub fn trace_one(
        &self,
        k: u32,
        points: (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> (f32, u64) {
        self.trace_at(k, points, base, &normal_matrix(&self.transform), ao)
    }

    /// [`trace_one`](Self::trace_one) with the snapshot's normal matrix
    /// `nm` given (made once for a slice).
    fn trace_at(
        &self,
        k: u32,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        nm: &glam::Mat3A,
        ao: &AoParams,
    ) -> (f32, u64) {
        let (p, n) = (local[k as usize], normals[k as usize]);
        let (p, n) = (
            self.transform.transform_point3(p),
            (*nm * n).normalize_or_zero(),
        );
        // Its rays drawn once: for the AO and for the count.
        let rays = self.tracer.point_rays(base + k, p, n, ao);
        let cast = rays.as_ref().map_or(0, |_| u64::from(ao.rays));
        (self.tracer.ao_of_rays(rays.as_ref(), ao), cast)
    }

    fn trace_range(
        &mut self,
        range: std::ops::Range<usize>,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> u64 {
        let nm = normal_matrix(&self.transform);
        let mut values: Vec<(f32, u64)> = self.todo[range]
            .par_iter()
            .with_min_len(64)
            .map(|&k| self.trace_at(k, (local, normals), base, &nm, ao))
            .collect();
        let cast = values.iter().map(|v| v.1).sum();
        self.ao.extend(values.drain(..).map(|v| v.0));
        cast
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_traces_its_points_in_slices_as_one_trace_would() {
        // A floor and a wall; the part's points near their corner.
        let tris = [
            [
                Vec3::new(-2.0, 0.0, -2.0),
                Vec3::new(2.0, 0.0, -2.0),
                Vec3::new(0.0, 0.0, 2.0),
            ],
            [
                Vec3::new(0.0, -1.0, -2.0),
                Vec3::new(0.0, 2.0, 0.0),
                Vec3::new(0.0, -1.0, 2.0),
            ],
        ];
        let tracer = AoTracer::new(&tris);
        let ao = AoParams {
            rays: 16,
            ..AoParams::default()
        };
        let local: Vec<Vec3> = (0..40)
            .map(|i| Vec3::new(0.05 + 0.01 * i as f32, 0.1, 0.0))
            .collect();
        let normals = vec![Vec3::Y; local.len()];
        let transform = Affine3A::from_translation(Vec3::new(0.02, 0.0, 0.1));
        let todo: Vec<u32> = (0..40).filter(|k| k % 3 != 1).collect();
        let mut stage = Stage::new((tracer.clone(), transform), todo.clone(), 7, 9);
        assert_eq!(todo.len(), 27);
        let mut slices = 0;
        while stage.left(ao.rays) > 7 * 16 {
            let before = stage.left(ao.rays);
            let cast = stage.trace_next(7 * 16 + 15, (&local, &normals), 100, &ao);
            // Whole points only: 7 of them.
            assert_eq!(before - stage.left(ao.rays), 7 * 16);
            assert_eq!(cast, 7 * 16);
            slices += 1;
        }
        assert_eq!(stage.trace_next(15, (&local, &normals), 100, &ao), 0);
        stage.trace_rest((&local, &normals), 100, &ao);
        assert_eq!(stage.left(ao.rays), 0);
        assert_eq!(slices, 3);
        // Every point's AO is the one tracing it whole at the snapshot's
        // pose gives, bit for bit; points not in the stage are not traced.
        let (ids, pts, nrm): (Vec<u32>, Vec<Vec3>, Vec<Vec3>) = (
            todo.iter().map(|&k| 100 + k).collect(),
            todo.iter()
                .map(|&k| transform.transform_point3(local[k as usize]))
                .collect(),
            todo.iter().map(|_| Vec3::Y).collect(),
        );
        let whole = tracer.trace_ids(&ids, &pts, &nrm, &ao).unwrap();
        for (j, &k) in todo.iter().enumerate() {
            assert_eq!(
                stage.traced(k).map(f32::to_bits),
                Some(whole.ao[j].to_bits())
            );
            assert_eq!(
                stage.trace_one(k, (&local, &normals), 100, &ao).0.to_bits(),
                whole.ao[j].to_bits()
            );
        }
        assert!(whole.ao.iter().any(|&a| a < 0.99), "the corner occludes");
        assert_eq!(stage.traced(1), None);
    }
}
