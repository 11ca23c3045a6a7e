//! The dirty set: the chosen points are traced (on the CPU or on the
//! backend) and compared with what clients hold; those past the thresholds
//! (all of them when forced) are set in their instance's table, whose
//! changes the next frame carries.

use glam::{Affine3A, Vec3};
use psao_codec::SentPoint;

use super::Pipeline;
use crate::error::SceneError;
use crate::model::pose::normal_matrix;
use crate::trace::ao::{AoTracer, ChangedPoints};

/// Points of every instance traced together, in world space.
struct Batch {
    /// Stable ids: instance `i`'s points are numbered after the points of
    /// the instances before it.
    ids: Vec<u32>,
    /// World positions.
    points: Vec<Vec3>,
    /// World normals.
    normals: Vec<Vec3>,
    /// (instance, point) of each traced point.
    owner: Vec<(usize, u32)>,
    /// What clients hold of each (cells numbered across instances).
    sent: Vec<SentPoint>,
}

impl Pipeline {
    /// Traces the listed points of each instance (world space) and sets the
    /// ones past the thresholds (all of them with `force`); buried points
    /// are not traced, and without `force` take their donors' AO now (the
    /// first trace, forced in batches, fills them once at its end).
    /// Returns (traced, rays, updated).
    pub(super) fn trace_and_update(
        &mut self,
        tracer: Option<&AoTracer>,
        which: &[Vec<u32>],
        force: bool,
    ) -> Result<(u64, u64, u64), SceneError> {
        let traced = self.traced_only(which);
        let batch = self.batch(traced.as_deref().unwrap_or(which), force);
        let result = self.trace_batch(tracer, &batch, force)?;
        self.apply(&batch.owner, &result)?;
        let filled = if traced.is_some() && !force {
            let touched: Vec<bool> = which.iter().map(|w| !w.is_empty()).collect();
            self.fill_buried(&touched, false)?
        } else {
            0
        };
        Ok((
            batch.ids.len() as u64,
            result.rays,
            result.changed.len() as u64 + filled,
        ))
    }

    /// The listed points of each instance in world space, with what clients
    /// hold of them (nothing with `force`).
    fn batch(&self, which: &[Vec<u32>], force: bool) -> Batch {
        let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
        // (instance, point) of each traced point, and what clients hold.
        let (mut owner, mut sent) = (Vec::new(), Vec::new());
        // Cells are numbered across instances: instance i's start after
        // the pools of those before it.
        let (mut base, mut cell_base) = (0u32, 0u32);
        for (i, (s, list)) in self.instances.iter().zip(which).enumerate() {
            if list.is_empty() {
                base += s.points.len() as u32;
                cell_base = cell_base.saturating_add(s.table.def().cell_pool);
                continue;
            }
            let nm = normal_matrix(&s.transform);
            // Traced where the points are now; compared where the table
            // stores them (bind space for a bind-space instance).
            let (positions, normals) = s.now();
            let (stored_p, stored_n) = s.stored();
            for &k in list {
                let (p, n) = (positions[k as usize], normals[k as usize]);
                ids.push(base + k);
                pts.push(s.transform.transform_point3(p));
                nrm.push((nm * n).normalize_or_zero());
                owner.push((i, k));
                sent.push(if force {
                    SentPoint::not_held(Vec3::ZERO)
                } else {
                    let (p, n) = (stored_p[k as usize], stored_n[k as usize]);
                    let mut held = s.table.sent(k, p, n);
                    held.cell = held.cell.saturating_add(cell_base);
                    held
                });
            }
            base += s.points.len() as u32;
            cell_base = cell_base.saturating_add(s.table.def().cell_pool);
        }
        Batch {
            ids,
            points: pts,
            normals: nrm,
            owner,
            sent,
        }
    }

    /// Traces `batch` and keeps the points past the thresholds against what
    /// clients hold: on the backend when there is one (placed first),
    /// otherwise with `tracer`, or a tracer over the scene now.
    fn trace_batch(
        &mut self,
        tracer: Option<&AoTracer>,
        batch: &Batch,
        force: bool,
    ) -> Result<ChangedPoints, SceneError> {
        let (ids, pts, nrm, sent) = (&batch.ids, &batch.points, &batch.normals, &batch.sent);
        let (ao, th) = (self.config.ao, self.config.thresholds);
        Ok(match (&mut self.backend, tracer) {
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
                    let r = backend.trace_ids(ids, pts, nrm, &ao)?;
                    ChangedPoints::compare(&r, sent, &th)?
                } else {
                    backend.trace_changed(ids, pts, nrm, sent, &ao, &th)?
                }
            }
            (None, Some(tracer)) => {
                ChangedPoints::compare(&tracer.trace_ids(ids, pts, nrm, &ao)?, sent, &th)?
            }
            (None, None) => ChangedPoints::compare(
                &self.tracer(false).trace_ids(ids, pts, nrm, &ao)?,
                sent,
                &th,
            )?,
        })
    }

    /// Sets each changed point of `result` in its instance's table (`owner`:
    /// the instance and point of each traced point), after checking that
    /// the result fits the batch.
    fn apply(&mut self, owner: &[(usize, u32)], result: &ChangedPoints) -> Result<(), SceneError> {
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
            let (positions, normals) = s.stored();
            let (p, n) = (positions[k as usize], normals[k as usize]);
            s.table.set_point(k, p, n, value)?;
        }
        Ok(())
    }
}
