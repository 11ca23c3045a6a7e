//! One server frame, [`Pipeline::step`], in its phases: animate and skin,
//! choose what motion can reach, cull per viewer, update the BVHs, trace
//! and apply the thresholds (the dirty set), encode. Each is timed in the
//! [`FrameReport`].

use std::time::Instant;

use glam::Vec3;
use psao_codec::EncodedFrame;

use super::blocks::{inside_any, overlaps};
use super::budget::RayBudget;
use super::config::{ViewerCull, Views};
use super::dirty::StepMotion;
use super::reach::MotionBoxes;
use super::report::FrameReport;
use super::{Pipeline, bounds_of};
use crate::error::{SceneError, check_param};
use crate::model::camera::Frustum;
use crate::model::mesh::transformed_bounds;
use crate::model::scene::check_transform;
use crate::trace::ao::{AoParams, AoTracer, ray_offset};
use crate::trace::geometry::RAY_LEAD;

/// Where a step's animation moved or deformed instances.
struct Motion {
    /// Per instance, whether it moved or deformed.
    changed: Vec<bool>,
    /// The skinned instances whose pose changed.
    deformed: Vec<usize>,
    /// The instances placed this step.
    placed: Vec<bool>,
    /// The world box each change swept (before and after), grown by what
    /// an AO ray reaches ([`grow`]).
    swept: Vec<(Vec3, Vec3)>,
    /// The same boxes, not grown: where what moved was, before and after.
    boxes: Vec<(Vec3, Vec3)>,
}

/// A box grown by what an AO ray from inside it reaches. A ray reaches R
/// beyond its origin, which sits `ray_offset` off the surface: grow boxes
/// by both (the offset at the box's farthest corner), plus a millimetre of
/// slack.
fn grow(ao: &AoParams, b: (Vec3, Vec3)) -> (Vec3, Vec3) {
    let far = b.0.abs().max(b.1.abs());
    let reach = ao.radius + ray_offset(ao.bias, far) + 1e-3;
    (b.0 - Vec3::splat(reach), b.1 + Vec3::splat(reach))
}

impl Pipeline {
    /// Advances the scene by `dt` seconds and produces the frame clients
    /// need, if any. Scene time is kept in f64, so a run is the same for
    /// the same sequence of steps.
    pub fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, FrameReport), SceneError> {
        check_param("dt", dt as f64, 0.0, 1e6, "finite, in [0, 1e6] seconds")?;
        let t0 = Instant::now();
        self.time += dt as f64;
        self.frame += 1;
        let mut report = FrameReport {
            points: self.instances.iter().map(|s| s.points.len() as u64).sum(),
            ..FrameReport::default()
        };
        let motion = self.animate(&mut report);
        report.t_animate = t0.elapsed();
        let t1 = Instant::now();
        let mut which = self.points_to_retrace(&motion);
        // Points that stopped early in the last step while their instance
        // has stopped moving now: traced in full, so that no early decision
        // outlives the motion.
        self.early_rested = std::mem::take(&mut self.last_early)
            .into_iter()
            .filter(|&k| {
                !motion
                    .changed
                    .get((k >> 32) as usize)
                    .copied()
                    .unwrap_or(true)
            })
            .collect();
        let mut grown = vec![false; which.len()];
        for &k in &self.early_rested {
            which[(k >> 32) as usize].push(k as u32);
            grown[(k >> 32) as usize] = true;
        }
        self.kept_scores.keep_moving(&motion.changed);
        // The lists they joined: ascending, each point once, again.
        for (w, _) in which.iter_mut().zip(&grown).filter(|(_, g)| **g) {
            w.sort_unstable();
            w.dedup();
        }
        if let Some(cull) = self.config.cull {
            report.culled = self.cull(&cull, &mut which);
        }
        report.t_select = t1.elapsed();
        let anything = which.iter().any(|w| !w.is_empty());
        let t2 = Instant::now();
        let tracer = self.update_bvhs(&motion, anything);
        report.t_bvh = t2.elapsed();
        let t3 = Instant::now();
        // Rigid movers held whole this step (their transform held back).
        let mut held = Vec::new();
        // Rigid movers whose stage ended: the pose their points were traced
        // in, for clients.
        let mut posed = Vec::new();
        // The envelope of what moves: points whose rays miss it need no
        // test while it holds. Taken every step, so that motion in a step
        // that traces nothing still counts.
        let moving: Vec<usize> = (0..motion.changed.len())
            .filter(|&i| motion.changed[i])
            .collect();
        if self.envelope.cover(&moving, &motion.boxes) {
            self.envelope_rays.clear();
            self.envelope_masks.clear();
        }
        if self.config.budget != RayBudget::Unlimited {
            report.wait_bound = self.wait_bound;
        }
        if anything || self.waiting.len() > 0 {
            let step = StepMotion {
                boxes: MotionBoxes::new(motion.boxes.iter().copied(), 4.0 * RAY_LEAD),
                envelope: MotionBoxes::new(self.envelope.boxes().iter().copied(), 4.0 * RAY_LEAD),
                changed: motion.changed.clone(),
                placed: motion.placed.clone(),
                period: dt as f64,
                elapsed: t0.elapsed(),
            };
            let tracer = match tracer {
                Some(t) => Some(t),
                // Only waiting points to trace: the tracer is built now.
                None if self.backend.is_none() => Some(self.tracer(false)),
                None => None,
            };
            let done = self.trace_step(tracer.as_ref(), &which, &step)?;
            report.traced = done.traced;
            report.rays = done.rays;
            report.updated = done.updated;
            report.unreached = done.unreached;
            report.rays_kept = done.rays_kept;
            report.budget = done.budget;
            report.overdue = done.overdue;
            report.verified = done.verified;
            report.settled = done.settled;
            report.early = done.early;
            report.open = done.open;
            report.rays_open = done.rays_open;
            report.trace_phases = done.phases;
            held = done.held;
            posed = done.posed;
        } else if !self.last_traced.is_empty() {
            // Nothing to trace: the points the last step traced settle.
            let settle = self.settle_left(&[])?;
            let filled = if self.instances.iter().any(|s| !s.buried.ids.is_empty()) {
                self.fill_buried(&settle.touched, false)?
            } else {
                0
            };
            report.updated = settle.updated + filled;
            report.settled = settle.updated;
        }
        report.waiting = self.waiting.len() as u64;
        report.oldest_wait = self.waiting.oldest();
        report.t_trace = t3.elapsed();

        let t4 = Instant::now();
        // What clients are sent of each transform: the current one, but
        // for a rigid mover held whole this step, or the pose of a stage
        // that ended.
        // (A transform that changed, or a placement, has a newer sequence.)
        let mut send = vec![false; self.instances.len()];
        for (i, transform) in posed {
            let s = &mut self.instances[i];
            // The stage's pose, under a sequence newer than any clients
            // hold; where the part is elsewhere by now (the stage ended
            // early, or its pose was not known ahead), the pose it is in
            // is newer still, so that it is at stake again.
            s.transform_seq = s.transform_seq.wrapping_add(1);
            (s.sent_transform, s.sent_seq) = (transform, s.transform_seq);
            if transform != s.transform {
                s.transform_seq = s.transform_seq.wrapping_add(1);
            }
            send[i] = true;
            held.resize(held.len().max(i + 1), false);
            held[i] = true;
        }
        for (i, s) in self.instances.iter_mut().enumerate() {
            if !held.get(i).copied().unwrap_or(false) && s.sent_seq != s.transform_seq {
                s.sent_transform = s.transform;
                s.sent_seq = s.transform_seq;
                send[i] = true;
            }
        }
        let frame = self.encode(&send, &mut report)?;
        report.t_encode = t4.elapsed();
        // What a step takes besides casting once its budget is set, for
        // an automatic budget.
        let ph = report.trace_phases;
        let tail = (ph.choose + ph.apply + report.t_encode).as_secs_f64();
        self.tail_s = 0.7 * self.tail_s + 0.3 * tail;
        Ok((frame, report))
    }

    /// The scene time a step to the pipeline's time poses, that time plus
    /// [`lead`](crate::PipelineConfig::lead), rounded to f32 (the step
    /// poses at [`posed_at`](Self::posed_at): once an animation has
    /// looped, `Scene::pose(posed_time())` may differ from the step's
    /// pose by the f32 rounding of the time).
    pub fn posed_time(&self) -> f32 {
        self.posed_at() as f32
    }

    /// [`posed_time`](Self::posed_time) in f64, the time the step's pose
    /// is made at (each animation's time within its loop taken in f64,
    /// [`Scene::pose_into_at`](crate::Scene::pose_into_at)).
    pub fn posed_at(&self) -> f64 {
        self.time + self.config.lead as f64
    }

    /// Animates the scene to the pipeline's time and takes each dynamic
    /// instance to its new pose (its transform, from the animation or
    /// [`place_instance`](Self::place_instance), and for a skinned one its
    /// skinned vertices and the points on them); remembers where motion
    /// happened (swept bounds). Counts deformed and held instances in
    /// `report`.
    fn animate(&mut self, report: &mut FrameReport) -> Motion {
        let ao = self.config.ao;
        // In f64: a server running for days poses its scene as finely as
        // in its first minute.
        self.scene.pose_into_at(self.posed_at(), &mut self.pose);
        let mut motion = Motion {
            changed: vec![false; self.instances.len()],
            deformed: Vec::new(),
            placed: vec![false; self.instances.len()],
            swept: Vec::new(),
            boxes: Vec::new(),
        };
        for (i, s) in self.instances.iter_mut().enumerate() {
            if !s.dynamic {
                continue;
            }
            let next = self.overrides[i].unwrap_or(self.pose.instances[i]);
            let joints = &self.pose.joints[i];
            let weights = &self.pose.weights[i];
            let deformed = !s.vertices.is_empty() && (*joints != s.joints || *weights != s.weights);
            let placed = std::mem::take(&mut self.placed[i]);
            motion.placed[i] = placed;
            if next == s.transform && !deformed {
                if placed {
                    // Placed where it already is: nothing to trace, but the
                    // placement is sent (a newer transform sequence).
                    s.transform_seq = s.transform_seq.wrapping_add(1);
                }
                continue;
            }
            // Work out the new state before changing anything: a degenerate
            // pose (a singular or non-finite transform, say an object
            // scaled to zero to hide it, or skinned vertices that overflow)
            // keeps the instance where it was.
            let inst = &self.scene.instances[i];
            let mesh = &self.scene.meshes[inst.mesh];
            let mut bounds = s.bounds;
            if deformed {
                self.scene.deform_into(
                    i,
                    &self.pose,
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
                // A placement waits for a pose that can be sent.
                self.placed[i] |= placed;
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
                s.weights.clone_from(weights);
                report.deformed += 1;
                motion.deformed.push(i);
            }
            let both = (before.0.min(after.0), before.1.max(after.1));
            motion.swept.push(grow(&ao, both));
            motion.boxes.push(both);
            if next != s.transform && s.positions.is_empty() {
                s.pose.note_move(&s.transform, &next, s.bounds);
            }
            if next != s.transform || placed {
                s.transform = next;
                s.transform_seq = s.transform_seq.wrapping_add(1);
            }
            motion.changed[i] = true;
        }
        motion
    }

    /// Chooses the points to re-trace, per instance: every point without
    /// skipping; otherwise every point of an instance that moved or
    /// deformed, and the points of the others that lie within what the
    /// motion can reach (its swept bounds).
    fn points_to_retrace(&self, motion: &Motion) -> Vec<Vec<u32>> {
        let ao = self.config.ao;
        let mut which: Vec<Vec<u32>> = vec![Vec::new(); self.instances.len()];
        if !self.config.skip {
            for (w, s) in which.iter_mut().zip(&self.instances) {
                *w = (0..s.points.len() as u32).collect();
            }
        } else if !motion.swept.is_empty() {
            let swept = &motion.swept;
            for (i, s) in self.instances.iter().enumerate() {
                if motion.changed[i] {
                    which[i] = (0..s.points.len() as u32).collect();
                    continue;
                }
                let wb = transformed_bounds(&s.transform, s.bounds);
                if !swept.iter().any(|&b| overlaps(b, grow(&ao, wb))) {
                    continue;
                }
                let positions = s.now().0;
                which[i] = if s.positions.is_empty() && s.blocks.covers(positions.len()) {
                    // A rigid instance's points, block by block.
                    s.blocks.within(positions, &s.transform, swept)
                } else {
                    (0..s.points.len() as u32)
                        .filter(|&k| {
                            inside_any(s.transform.transform_point3(positions[k as usize]), swept)
                        })
                        .collect()
                };
            }
        }
        which
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
                        path.at(self.posed_time())
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
        for (i, (s, w)) in self.instances.iter_mut().zip(which.iter_mut()).enumerate() {
            for &k in w.iter() {
                s.pending[k as usize] = true;
            }
            // This step's own points; the others pending waited out of view.
            let mut fresh = std::mem::take(w);
            fresh.sort_unstable();
            // The points now (a rigid instance's are its points' own),
            // borrowed apart from the pending flags.
            let now = if s.positions.is_empty() {
                &s.points.positions
            } else {
                &s.positions
            };
            for (k, pending) in s.pending.iter_mut().enumerate() {
                if !*pending {
                    continue;
                }
                let p = s.transform.transform_point3(now[k]);
                if everything || frusta.iter().any(|f| f.touches_sphere(p, reach)) {
                    *pending = false;
                    w.push(k as u32);
                    if fresh.binary_search(&(k as u32)).is_err() {
                        // Back in view after motion reached it out of view:
                        // traced in full, whatever this step's reach says.
                        self.waiting.wait(super::ray_cache::key(i, k as u32), true);
                    }
                } else {
                    // Motion may reach its rays while it waits out of
                    // view: it is traced in full when it comes back.
                    self.ray_cache.forget(super::ray_cache::key(i, k as u32));
                    waiting += 1;
                }
            }
        }
        waiting
    }

    /// Brings the BVHs up to date with the motion: refits the deformed
    /// instances' own BVHs (split BVH), or drops the one BVH over
    /// everything when anything changed (rebuilt the next time something is
    /// traced). Returns the CPU tracer when there is `anything` to trace
    /// and no backend.
    fn update_bvhs(&mut self, motion: &Motion, anything: bool) -> Option<AoTracer> {
        if self.config.split_bvh {
            self.refit_deformed(&motion.deformed);
        } else if motion.changed.contains(&true) {
            // Rebuilt the next time something is traced.
            self.whole_layer = None;
        }
        (anything && self.backend.is_none()).then(|| self.tracer(false))
    }

    /// Encodes the frame: the transforms clients are to hold of the
    /// instances in `send` and every table's changes (the dirty set);
    /// `None` when there is nothing to say. Counts transforms and bytes in
    /// `report`.
    fn encode(
        &mut self,
        send: &[bool],
        report: &mut FrameReport,
    ) -> Result<Option<EncodedFrame>, SceneError> {
        let mut frame = self.encoder.delta();
        for (i, s) in self.instances.iter_mut().enumerate() {
            if send[i] {
                frame.transform(s.table.id(), s.sent_seq, &s.sent_transform.to_cols_array());
                report.transforms += 1;
            }
            frame.changes(&mut s.table);
        }
        let frame = frame.finish()?;
        report.bytes = frame.as_ref().map_or(0, |f| f.bytes.len() as u64);
        Ok(frame)
    }
}
