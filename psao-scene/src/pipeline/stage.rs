//! A rigid mover traced whole over several steps at one pose (a *stage*).
//!
//! Under [`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)
//! a moving rigid part's points are traced together, and clients hold the
//! part's transform at the pose they were traced in. A part whose points
//! cost more than a step's budget was held until it fit, or for
//! [`max_wait`](super::config::PipelineConfig::max_wait) steps and then
//! traced in one step several periods long. On the CPU a held part is
//! now traced in slices instead: the step that holds it keeps the scene
//! as it is then (its [`AoTracer`], whose layers are shared, and the
//! part's transform), and each step traces a slice of the part's points
//! against that snapshot, at the pose of the snapshot. The step that
//! takes the last slice sets them all, and clients get the snapshot's
//! transform with them: the part's AO arrives whole and consistent, some
//! steps late, as from a slower server, and no step runs past its budget
//! for it.

use glam::{Affine3A, Vec3};
use rayon::prelude::*;

use crate::model::pose::normal_matrix;
use crate::trace::ao::{AoParams, AoTracer};

/// One part's stage: the scene as it was posed when it began, and the
/// points traced so far.
pub(super) struct Stage {
    /// The scene posed at the stage's first step (layers shared).
    tracer: AoTracer,
    /// The part's transform then, and its sequence: what clients get
    /// with the points.
    pub transform: Affine3A,
    pub seq: u32,
    /// The points to trace, ascending.
    todo: Vec<u32>,
    /// How many of `todo` are traced; their AO, in `todo`'s order.
    ao: Vec<f32>,
    /// Rays each step spends on it at least: its points' rays over the
    /// steps it is to end within.
    pub share: u64,
}

impl Stage {
    /// A stage of `todo` (ascending, deduplicated) against `tracer`, the
    /// part at `transform` (sequence `seq`); each point costs `rays`, and
    /// the stage is to end within `steps` steps.
    pub fn new(
        tracer: AoTracer,
        (transform, seq): (Affine3A, u32),
        todo: Vec<u32>,
        rays: u32,
        steps: u32,
    ) -> Stage {
        // Whole points a step.
        let per_step = (todo.len() as u64).div_ceil(u64::from(steps.max(1)));
        Stage {
            tracer,
            transform,
            seq,
            ao: Vec::with_capacity(todo.len()),
            todo,
            share: per_step * u64::from(rays),
        }
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
    /// (at least one while any is left), at the snapshot's pose: `local`
    /// and `normals` are the part's points in its own space, `base` the
    /// id of its point 0. Returns the rays cast.
    pub fn trace_next(
        &mut self,
        rays: u64,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> u64 {
        let per = u64::from(ao.rays.max(1));
        let n = usize::try_from(rays / per).unwrap_or(usize::MAX).max(1);
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
    /// part that joined after the stage began).
    pub fn trace_one(
        &self,
        k: u32,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> f32 {
        let nm = normal_matrix(&self.transform);
        let (p, n) = (local[k as usize], normals[k as usize]);
        self.tracer.point_ao(
            base + k,
            self.transform.transform_point3(p),
            (nm * n).normalize_or_zero(),
            ao,
        )
    }

    fn trace_range(
        &mut self,
        range: std::ops::Range<usize>,
        (local, normals): (&[Vec3], &[Vec3]),
        base: u32,
        ao: &AoParams,
    ) -> u64 {
        let nm = normal_matrix(&self.transform);
        let (tracer, transform) = (&self.tracer, self.transform);
        let mut values: Vec<(f32, bool)> = self.todo[range]
            .par_iter()
            .with_min_len(64)
            .map(|&k| {
                let (p, n) = (local[k as usize], normals[k as usize]);
                let (p, n) = (transform.transform_point3(p), (nm * n).normalize_or_zero());
                let cast = tracer.point_rays(base + k, p, n, ao).is_some();
                (tracer.point_ao(base + k, p, n, ao), cast)
            })
            .collect();
        let cast = values.iter().filter(|v| v.1).count() as u64 * u64::from(ao.rays);
        self.ao.extend(values.drain(..).map(|v| v.0));
        cast
    }
}

/// The rays a step spends on `stage` under a budget of `budget` rays:
/// its share, or half the budget where that is more (the other half for
/// the rest of the step's points).
pub(super) fn stage_rays(stage: &Stage, budget: u64) -> u64 {
    stage.share.max(budget / 2)
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
        let mut stage = Stage::new(tracer.clone(), (transform, 7), todo.clone(), ao.rays, 4);
        // 27 points over 4 steps: 7 a step.
        assert_eq!(todo.len(), 27);
        assert_eq!(stage.share, 7 * 16);
        let mut slices = 0;
        while stage.left(ao.rays) > stage.share {
            let before = stage.left(ao.rays);
            let cast = stage.trace_next(stage.share, (&local, &normals), 100, &ao);
            assert_eq!(before - stage.left(ao.rays), cast);
            slices += 1;
        }
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
                stage.trace_one(k, (&local, &normals), 100, &ao).to_bits(),
                whole.ao[j].to_bits()
            );
        }
        assert!(whole.ao.iter().any(|&a| a < 0.99), "the corner occludes");
        assert_eq!(stage.traced(1), None);
    }
}
