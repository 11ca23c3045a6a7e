//! The dirty set: the chosen points are traced (on the CPU or on the
//! backend) and compared with what clients hold; those past the thresholds
//! (all of them when forced) are set in their instance's table, whose
//! changes the next frame carries.

use std::time::Duration;

use glam::{Affine3A, Vec3, Vec3A};
use psao_codec::{SentPoint, Thresholds};
use rayon::prelude::*;

use super::Pipeline;
use super::backend::{AoBackend, RayJob};
use super::budget::{due, next_bound, ns_per_priced_ray, select};
use super::config::MoversWhole;
use super::early::Kept;
use super::plan::{Learnt, Plan};
use super::ray_cache::key;
use super::reach::MotionBoxes;
use super::report::TracePhases;
use super::stage::Stage;
use super::work::{Moving, PointWork, Traced};
use crate::error::SceneError;
use crate::model::pose::normal_matrix;
use crate::model::scene::check_transform;
use crate::morton::morton_order;
use crate::trace::ao::{AoParams, AoResult, AoTracer, ChangedPoints, PointRays};
use psao_codec::wire::point::{dequantize_ao, quantize_ao};

/// What casting a step's chosen points gave: their values, and the rays
/// the points known open would have cast but did not (the budget paid
/// for them: an automatic budget prices a ray over both,
/// [`ns_per_priced_ray`]).
struct Cast {
    /// Each point's AO, and the rays cast.
    values: AoResult,
    /// The rays the points known open would have cast.
    rays_open: u64,
}

/// The fewest points a parallel pass over a step's points hands a thread
/// (below that, handing work out costs more than it saves).
pub(super) const PAR_MIN: usize = 1024;

/// What a step's motion means for tracing ([`Pipeline::trace_step`]).
pub(super) struct StepMotion {
    /// Where what moved was, before and after the step.
    pub boxes: MotionBoxes,
    /// The envelope of what moves (`reach::Envelope`): a point none of
    /// whose rays reaches it is not tested again while it holds.
    pub envelope: MotionBoxes,
    /// Per instance, whether it moved or deformed: its points are traced
    /// in full.
    pub changed: Vec<bool>,
    /// Per instance, whether it was placed this step (a placement is sent
    /// in its step: never held back).
    pub placed: Vec<bool>,
    /// The step's period, seconds (an automatic budget's share of it).
    pub period: f64,
    /// Time the step took before tracing.
    pub elapsed: Duration,
}

/// What [`Pipeline::trace_step`] did.
pub(super) struct StepTrace {
    pub traced: u64,
    pub rays: u64,
    pub updated: u64,
    pub unreached: u64,
    pub rays_kept: u64,
    pub budget: Option<u64>,
    pub overdue: u64,
    /// Waiting points whose wait the loop memory started again.
    pub verified: u64,
    pub settled: u64,
    pub early: u64,
    /// Points known open without a ray ([`Plan::Open`]).
    pub open: u64,
    /// The rays those points were priced at and did not cast.
    pub rays_open: u64,
    /// The trace phase's parts: planning, choosing, casting, and what
    /// follows (see [`TracePhases`]).
    pub phases: TracePhases,
    /// Per instance, whether the step held it whole (a rigid mover whose
    /// points wait together, its transform held back with them: see
    /// [`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)).
    pub held: Vec<bool>,
    /// The instances whose stage ended this step ([`Stage`]), with the
    /// transform clients get in place of the current one.
    pub posed: Vec<(usize, Affine3A)>,
}

/// A step's stages ([`Pipeline::stages_of_step`]): the slices to trace,
/// (instance, rays), and the stages that end, (instance, stage).
type StagesOfStep = (Vec<(usize, u64)>, Vec<(usize, Stage)>);

/// What [`Pipeline::settle_left`] did.
pub(super) struct Settled {
    /// Per instance, whether any of its points was set.
    pub touched: Vec<bool>,
    /// Points set.
    pub updated: u64,
}

/// Points of every instance traced together, in world space.
#[derive(Default)]
pub(super) struct Batch {
    /// Stable ids: instance `i`'s points are numbered after the points of
    /// the instances before it.
    pub ids: Vec<u32>,
    /// World positions.
    pub points: Vec<Vec3>,
    /// World normals.
    pub normals: Vec<Vec3>,
    /// (instance, point) of each traced point.
    pub owner: Vec<(usize, u32)>,
    /// What clients hold of each (cells numbered across instances).
    pub sent: Vec<SentPoint>,
}

impl Batch {
    /// The entries at `at` (ascending), in that order (`sent` too where
    /// it is looked up).
    pub(super) fn select(&self, at: &[usize]) -> Batch {
        let mut out = Batch::default();
        for &b in at {
            out.ids.push(self.ids[b]);
            out.points.push(self.points[b]);
            out.normals.push(self.normals[b]);
            out.owner.push(self.owner[b]);
            if let Some(&h) = self.sent.get(b) {
                out.sent.push(h);
            }
        }
        out
    }
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
        let th = self.config.thresholds;
        let result = self.trace_batch(tracer, &batch, force, &th)?;
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

    /// Traces what a step's motion needs: the points listed in `which` and
    /// those waiting from earlier steps, each only where motion can reach
    /// its rays (with [`PipelineConfig::ray_reuse`]), within the step's ray
    /// budget; sets the ones past the thresholds. Buried points take their
    /// donors' AO as in [`Self::trace_and_update`].
    ///
    /// [`PipelineConfig::ray_reuse`]: super::config::PipelineConfig::ray_reuse
    pub(super) fn trace_step(
        &mut self,
        tracer: Option<&AoTracer>,
        which: &[Vec<u32>],
        motion: &StepMotion,
    ) -> Result<StepTrace, SceneError> {
        // The budget pays for what follows, the waiting list included.
        let started = std::time::Instant::now();
        self.remember_motion(motion);
        let mut lists = self.traced_only(which).unwrap_or_else(|| which.to_vec());
        let rays = self.config.ao.rays;
        let (apart, mut touched) = self.split_waiting(&mut lists, motion);
        // What clients hold is looked up for the points traced only.
        let batch = self.batch_unheld(&lists);
        let (plans, learnt): (Vec<Plan>, Vec<Learnt>) =
            self.plan(&batch, motion).into_iter().unzip();
        self.remember_envelope(&batch, learnt);
        let budget = self.step_budget(motion, started);
        // From here to casting (choosing, the waiting list, what clients
        // hold) is paid for with the step's tail.
        let budgeted = std::time::Instant::now();
        // The bound on waiting in force for this step.
        let bound = self.wait_bound;
        let cands = self.candidates(&batch, &plans, &apart, motion, bound, budget);
        // Parts held whole: their transform stays what clients hold.
        let held: Vec<bool> = cands.whole.iter().map(|w| *w == Some(false)).collect();
        for (s, w) in self.instances.iter_mut().zip(&cands.whole) {
            match w {
                Some(false) => s.held_steps += 1,
                // Traced whole, or not held (its transform goes out).
                Some(true) | None => s.held_steps = 0,
            }
        }
        // Parts traced whole over several steps: their slices are paid
        // for first.
        let (slices, mut finishing) =
            self.stages_of_step(tracer, (&batch, &apart), &cands, motion, (budget, bound));
        let staged_rays: u64 = slices.iter().map(|s| s.1).sum();
        let rest = budget.map(|b| b.saturating_sub(staged_rays));
        let (mut chosen, spent) = select(&cands.all, rest, bound);
        let late = self.plan_late(&apart, &cands, &mut chosen, (rest, spent, bound));
        // Overdue points, and the rays of those that really waited: what
        // moves the bound.
        let (overdue, forced) = cands
            .merged
            .iter()
            .zip(&cands.all)
            .filter(|(_, c)| budget.is_some() && c.overdue(bound))
            .fold((0u64, 0u64), |(n, r), (&(a, j), c)| {
                let really = if a {
                    cands.apart_really[j]
                } else {
                    cands.waited_really[j]
                };
                (n + 1, r + if really { c.cost as u64 } else { 0 })
            });
        let (take, take_apart, verified) =
            self.record_choices(&batch, &plans, &apart, &cands, &chosen, bound);
        if let Some(b) = budget {
            let (least, limit) = (self.config.max_wait, self.config.max_wait_limit);
            let oldest = self.waiting.oldest();
            self.wait_bound = next_bound(bound, forced, b, oldest, least, limit);
        }
        // The chosen points, planned and apart, in (instance, point) order.
        let (full, open) = (Plan::Full { reached: rays }, Plan::Open);
        let (mut sub, mut sub_plans) =
            self.chosen_batch((&batch, &plans), &take, &take_apart, (&late, &full));
        if let Some(t) = tracer {
            // Not the points of a part whose stage ends now: the stage
            // gives their AO, whatever their plan.
            let staged: Vec<usize> = finishing.iter().map(|f| f.0).collect();
            self.known_open(t, (&sub, &staged), &mut sub_plans, &open);
        }
        self.look_up_held(&mut sub);
        let casting = std::time::Instant::now();
        // Rays the points known open would have cast but did not.
        let mut rays_open = 0;
        let mut rays_staged = self.trace_slices(&slices);
        let th = self.config.thresholds;
        let settling = self.config.settle_steps > 0;
        // Under a budget every value comes back for the points' trends.
        let every_value = settling || budget.is_some();
        // A backend that casts single rays follows the CPU's rules.
        let planned_on_backend = self.planned_on_backend();
        let (result, settled) = if self.backend.is_some() && !planned_on_backend && !every_value {
            // Compared where it was traced.
            (self.trace_batch(tracer, &sub, false, &th)?, 0)
        } else {
            let cast = if planned_on_backend {
                self.place_backend()?;
                self.trace_planned(None, &sub, &sub_plans, &motion.changed)?
            } else if self.backend.is_some() {
                Cast {
                    values: self.trace_values(&sub)?,
                    rays_open: 0,
                }
            } else {
                let owned = tracer.is_none().then(|| self.tracer(false));
                let tracer = tracer.or(owned.as_ref()).expect("a tracer");
                if finishing.is_empty() {
                    self.trace_planned(Some(tracer), &sub, &sub_plans, &motion.changed)?
                } else {
                    let (cast, staged) = self.trace_finishing(
                        tracer,
                        (&sub, &sub_plans),
                        &motion.changed,
                        &mut finishing,
                    )?;
                    rays_staged += staged;
                    cast
                }
            };
            rays_open = cast.rays_open;
            let values = cast.values;
            let compared = self.compare_remembered(&values, &sub)?;
            self.note_loop(&values, &sub, &finishing);
            compared
        };
        let (traced, rays_cast) = (sub.ids.len() as u64, result.rays + rays_staged);
        let t_after = std::time::Instant::now();
        let mut phases = TracePhases {
            plan: budgeted.duration_since(started),
            choose: casting.duration_since(budgeted),
            cast: t_after.duration_since(casting),
            apply: Duration::ZERO,
        };
        let open = sub_plans.iter().filter(|p| matches!(p, Plan::Open)).count() as u64;
        // The cost of a ray the budget pays for, for an automatic budget:
        // a running mean over the casting alone (planning is paid for
        // apart).
        if let Some(ns) = ns_per_priced_ray(casting.elapsed(), rays_cast, rays_open) {
            self.ray_ns = if self.ray_ns > 0.0 {
                0.7 * self.ray_ns + 0.3 * ns
            } else {
                ns
            };
        }
        let planned: u64 = sub_plans.iter().map(|p| u64::from(p.cost(rays))).sum();
        self.apply(&sub.owner, &result)?;
        let settle = self.settle_left(&sub.owner)?;
        for (t, s) in touched.iter_mut().zip(&settle.touched) {
            *t |= *s;
        }
        let filled = if self.instances.iter().any(|s| !s.buried.ids.is_empty()) {
            self.fill_buried(&touched, false)?
        } else {
            0
        };
        phases.apply = t_after.elapsed();
        Ok(StepTrace {
            traced,
            rays: rays_cast,
            updated: result.changed.len() as u64 + settle.updated + filled,
            settled: settled + settle.updated,
            unreached: cands.unreached,
            // An open point's rays are known, not kept.
            rays_kept: ((traced - open) * rays as u64).saturating_sub(planned),
            budget,
            overdue,
            verified,
            early: self.last_early.len() as u64,
            open,
            rays_open,
            phases,
            held,
            posed: finishing
                .into_iter()
                .map(|(i, stage)| (i, stage.transform))
                .collect(),
        })
    }

    /// The stages of a step ([`Stage`], under
    /// [`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)
    /// on the CPU): a part held (`cands.whole` `Some(false)`) begins one of
    /// its candidates, planned ([`Self::plan_stage`]); a held part's stage
    /// traces its next slice (returned as (instance, rays), within what is
    /// left of `budget`); a part traced whole ends its stage (returned,
    /// taken out) where it ends as planned ([`Stage::ends_as_planned`]);
    /// a part placed, made to end early at another pose, or with nothing
    /// to trace, drops it (its points are then traced as without stages).
    fn stages_of_step(
        &mut self,
        tracer: Option<&AoTracer>,
        (batch, apart): (&Batch, &super::choose::Apart),
        cands: &super::choose::Candidates,
        motion: &StepMotion,
        (budget, bound): (Option<u64>, u32),
    ) -> StagesOfStep {
        let (mut slices, mut finishing) = (Vec::new(), Vec::new());
        let staging = self.config.movers_whole != MoversWhole::Off && self.backend.is_none();
        let rays = self.config.ao.rays;
        let mut left = budget.unwrap_or(0);
        for i in 0..self.instances.len() {
            let whole = cands.whole.get(i).copied().flatten();
            if whole.is_none() || motion.placed.get(i).copied().unwrap_or(false) || !staging {
                self.stages[i] = None;
            }
            match whole {
                Some(true) => {
                    let now = self.instances[i].transform;
                    if let Some(stage) = self.stages[i].take()
                        && stage.ends_as_planned(self.frame, &now)
                    {
                        finishing.push((i, stage));
                    }
                }
                Some(false) => {
                    if self.stages[i].is_none()
                        && let Some(tracer) = tracer.filter(|_| staging)
                    {
                        // Its candidates, ascending (merged in key order).
                        let todo: Vec<u32> = (cands.merged.iter())
                            .map(|&(a, j)| {
                                if a {
                                    apart.keys[j]
                                } else {
                                    let (i, k) = batch.owner[cands.at[j]];
                                    key(i, k)
                                }
                            })
                            .filter(|&k| (k >> 32) as usize == i)
                            .map(|k| k as u32)
                            .collect();
                        let stage =
                            self.plan_stage(i, todo, tracer, motion.period, (budget, bound));
                        self.stages[i] = Some(stage);
                    }
                    if let Some(stage) = &self.stages[i] {
                        let slice = (stage.slice as u64 * u64::from(rays))
                            .min(stage.left(rays))
                            .min(left);
                        left -= slice;
                        slices.push((i, slice));
                    }
                }
                None => {}
            }
        }
        (slices, finishing)
    }

    /// Plans the stage of rigid mover `i`'s points `todo` (ascending), held
    /// this step under `budget` and `bound`: the points a step traces,
    /// enough to end before the first of them comes due (and before the
    /// part has been held `max_wait` steps), and at least half a budget's
    /// worth; so the step it ends in; and the scene with the part posed
    /// for that step ([`Self::posed_ahead`]; the scene now, `tracer`,
    /// where that pose is not known).
    fn plan_stage(
        &mut self,
        i: usize,
        todo: Vec<u32>,
        tracer: &AoTracer,
        period: f64,
        (budget, bound): (Option<u64>, u32),
    ) -> Stage {
        let rays = self.config.ao.rays.max(1);
        let held = self.instances[i].held_steps;
        let steps = (todo.iter())
            .map(|&k| {
                let age = self.waiting.get(key(i, k)).map_or(0, |w| w.0);
                due(key(i, k), bound).saturating_sub(age).saturating_sub(1)
            })
            .min()
            .unwrap_or(1)
            .clamp(1, self.config.max_wait.saturating_sub(held).max(1));
        let points = todo.len() as u64;
        let half = budget.unwrap_or(0) / 2 / u64::from(rays);
        let slice = points.div_ceil(u64::from(steps)).max(half).max(1);
        // Its first slice this step, its last (the rest) `takes - 1` steps
        // on.
        let takes = points.div_ceil(slice).max(2);
        let (tracer, transform) = match self.posed_ahead(i, takes - 1, period) {
            Some(there) => there,
            None => (tracer.clone(), self.instances[i].transform),
        };
        let slice = usize::try_from(slice).unwrap_or(usize::MAX);
        Stage::new((tracer, transform), todo, slice, self.frame + takes - 1)
    }

    /// The scene as a stage of rigid mover `i` traces it, posed `steps`
    /// steps of `period` seconds after this one (the scene time those
    /// steps will pose, added up as they add it): the part where its
    /// animation (or its placement) takes it by then, the rest as now;
    /// with that transform.
    /// `None` where it is where it is now, where the BVH is not split
    /// (one BVH over the world), or where that pose is unsound (then the
    /// stage traces the scene now).
    fn posed_ahead(&mut self, i: usize, steps: u64, period: f64) -> Option<(AoTracer, Affine3A)> {
        if steps == 0 || !self.config.split_bvh {
            return None;
        }
        let s = self.instances.get(i)?;
        let there = match self.overrides.get(i).copied().flatten() {
            Some(t) => t,
            None => {
                let mut time = self.time;
                for _ in 0..steps.min(1 << 16) {
                    time += period as f32 as f64;
                }
                let mut pose = self.pose.clone();
                // At the f64 time, as the step poses it.
                self.scene
                    .pose_into_at(time + self.config.lead as f64, &mut pose);
                *pose.instances.get(i)?
            }
        };
        if there == s.transform || check_transform(i, &there, Some(s.bounds)).is_err() {
            return None;
        }
        let now = std::mem::replace(&mut self.instances[i].transform, there);
        let tracer = self.tracer(false);
        self.instances[i].transform = now;
        Some((tracer, there))
    }

    /// The id of each instance's point 0 (its points numbered after those
    /// of the instances before it).
    fn id_bases(&self) -> Vec<u32> {
        let mut next = 0u32;
        (self.instances.iter())
            .map(|s| {
                let base = next;
                next = next.saturating_add(s.points.len() as u32);
                base
            })
            .collect()
    }

    /// Traces each stage's slice of `slices` ((instance, rays)); returns
    /// the rays cast.
    fn trace_slices(&mut self, slices: &[(usize, u64)]) -> u64 {
        if slices.is_empty() {
            return 0;
        }
        let bases = self.id_bases();
        let ao = self.config.ao;
        let mut cast = 0;
        for &(i, rays) in slices {
            if let (Some(stage), Some(s)) = (self.stages[i].as_mut(), self.instances.get(i)) {
                cast += stage.trace_next(rays, s.now(), bases[i], &ao);
            }
        }
        cast
    }

    /// Traces `sub` (with its plans) as [`trace_planned`](Self::trace_planned)
    /// does, but for the points of the parts whose stage ends (`finishing`):
    /// those take the AO their stage traced at its pose (what is left of
    /// it traced now, and a point that joined the part's candidates since
    /// it began traced against its snapshot). Returns what was cast (the
    /// points of those parts know none open: their plans are not used)
    /// and the rays the stages cast.
    fn trace_finishing(
        &mut self,
        tracer: &AoTracer,
        (sub, plans): (&Batch, &[&Plan]),
        changed: &[bool],
        finishing: &mut [(usize, Stage)],
    ) -> Result<(Cast, u64), SceneError> {
        let bases = self.id_bases();
        let ao = self.config.ao;
        let mut cast = 0;
        for (i, stage) in finishing.iter_mut() {
            cast += stage.trace_rest(self.instances[*i].now(), bases[*i], &ao);
        }
        let staged: Vec<Option<f32>> = (sub.owner.iter())
            .map(|&(i, k)| {
                let (_, stage) = finishing.iter().find(|f| f.0 == i)?;
                // Scores kept from an earlier trace (early decisions) are
                // not this trace's: forgotten.
                drop(self.kept_scores.take(key(i, k)));
                Some(stage.traced(k).unwrap_or_else(|| {
                    let (value, rays) = stage.trace_one(k, self.instances[i].now(), bases[i], &ao);
                    cast += rays;
                    value
                }))
            })
            .collect();
        let at: Vec<usize> = (0..staged.len()).filter(|&b| staged[b].is_none()).collect();
        let rest_plans: Vec<&Plan> = at.iter().map(|&b| plans[b]).collect();
        let rest_cast = self.trace_planned(Some(tracer), &sub.select(&at), &rest_plans, changed)?;
        let values = rest_cast.values;
        let mut rest = values.ao.into_iter();
        let ao = staged
            .iter()
            .map(|v| v.unwrap_or_else(|| rest.next().unwrap_or(1.0)))
            .collect();
        Ok((
            Cast {
                values: AoResult {
                    ao,
                    rays: values.rays,
                },
                rays_open: rest_cast.rays_open,
            },
            cast,
        ))
    }

    /// Compares the AO `values` traced for `batch` with what clients hold,
    /// and remembers them as each point's last trace. A point goes out when
    /// it passes the thresholds, or when it has *settled*: its trace gave
    /// the same AO (to the quantization) as the one before, so motion
    /// changes it no more, and that is at least
    /// [`settle_steps`](super::PipelineConfig::settle_steps) from what
    /// clients hold. (A point whose rays motion no longer reaches is not
    /// traced again, and [`settle_left`](Self::settle_left) settles it the
    /// same way, so frames do not depend on ray reuse.)
    fn compare_remembered(
        &mut self,
        values: &AoResult,
        batch: &Batch,
    ) -> Result<(ChangedPoints, u64), SceneError> {
        let th = self.config.thresholds;
        let steps = self.config.settle_steps;
        // Each point's last trace, kept (choosing reads it too), and
        // whether it repeated the one before (for settling).
        let mut repeated = Vec::with_capacity(if steps > 0 { batch.owner.len() } else { 0 });
        for (&(i, k), &ao) in batch.owner.iter().zip(&values.ao) {
            let q = quantize_ao(ao);
            let same = match self.instances[i].last_ao.get_mut(k as usize) {
                Some(last) => std::mem::replace(last, q) == q,
                None => false,
            };
            if steps > 0 {
                repeated.push(same);
            }
        }
        if steps == 0 {
            // Nothing settles.
            let out = ChangedPoints::compare(values, &batch.sent, &th)?;
            self.note_trend(values, batch, &out.changed);
            return Ok((out, 0));
        }
        let mut settle = th;
        settle.ao_steps = th.ao_steps.min(steps - 1);
        let out = ChangedPoints::compare_each(values, &batch.sent, |b| {
            if repeated[b] { settle } else { th }
        })?;
        // Those the thresholds alone would not have sent.
        let settled = out
            .changed
            .iter()
            .zip(&out.ao)
            .filter(|&(&b, &ao)| !batch.sent[b as usize].changed(ao, &th))
            .count() as u64;
        self.note_trend(values, batch, &out.changed);
        Ok((out, settled))
    }

    /// Notes the `Trend` of each point of `batch` (kept under a budget
    /// only) from the AO `values` traced, `changed` (indices into
    /// `batch`) those that went out. A point that stopped early (its value is what
    /// clients hold, not a trace) keeps its trend.
    fn note_trend(&mut self, values: &AoResult, batch: &Batch, changed: &[u32]) {
        if self.instances.iter().all(|s| s.trend.is_empty()) {
            return;
        }
        let now = self.frame as u32;
        let mut went = vec![false; batch.owner.len()];
        for &c in changed {
            if let Some(w) = went.get_mut(c as usize) {
                *w = true;
            }
        }
        // Per instance, points traced (not stopped early) and of them
        // those that went out.
        let mut counts = vec![(0u32, 0u32); self.instances.len()];
        for (b, (&(i, k), &ao)) in batch.owner.iter().zip(&values.ao).enumerate() {
            let went_out = went[b];
            if self.instances[i].trend.is_empty()
                || self.last_early.binary_search(&key(i, k)).is_ok()
            {
                continue;
            }
            let held = batch
                .sent
                .get(b)
                .map(|s| s.word)
                .filter(|w| w.is_allocated());
            counts[i].0 += 1;
            counts[i].1 += u32::from(went_out);
            let s = &mut self.instances[i];
            if let Some(t) = s.trend.get_mut(k as usize) {
                let pace = t.note(quantize_ao(ao), held.map(|w| w.fields().ao), now, went_out);
                match s.points.positions.get(k as usize) {
                    Some(&p) if s.keeps_heat() => s.heat.note(p, pace, now),
                    _ => {}
                }
            }
        }
        for (s, &(traced, sent)) in self.instances.iter_mut().zip(&counts) {
            if traced > 0 && s.keeps_heat() {
                s.pose.note(traced, sent);
            }
        }
        for s in &mut self.instances {
            s.heat.cool(now);
        }
    }

    /// Notes in the loop memory (if any) the AO `values` traced for
    /// `batch` at this step's moment of the scene's loop: not the points
    /// that stopped early (their value is what clients hold, not a trace),
    /// nor those of the parts whose stage ends (`finishing`: traced at
    /// their stage's pose).
    fn note_loop(&mut self, values: &AoResult, batch: &Batch, finishing: &[(usize, Stage)]) {
        let Some(at) = self.loop_moment() else {
            return;
        };
        let Some(memory) = self.loop_memory.as_mut() else {
            return;
        };
        for (&(i, k), &ao) in batch.owner.iter().zip(&values.ao) {
            let k = key(i, k);
            if finishing.iter().any(|(f, _)| *f == i) || self.last_early.binary_search(&k).is_ok() {
                continue;
            }
            memory.note(k, at, quantize_ao(ao));
        }
    }

    /// Traces `batch` on the backend (placed first) and reads every AO
    /// back, for [`compare_remembered`](Self::compare_remembered).
    fn trace_values(&mut self, batch: &Batch) -> Result<AoResult, SceneError> {
        let ao = self.config.ao;
        self.place_backend()?;
        let backend = self.backend.as_mut().expect("a backend");
        backend.trace_ids(&batch.ids, &batch.points, &batch.normals, &ao)
    }

    /// Places the scene as it is now on the backend (none: nothing).
    fn place_backend(&mut self) -> Result<(), SceneError> {
        let transforms: Vec<Affine3A> = self.instances.iter().map(|s| s.transform).collect();
        let vertices: Vec<Option<&[Vec3]>> = self
            .instances
            .iter()
            .map(|s| (!s.vertices.is_empty()).then_some(s.vertices.as_slice()))
            .collect();
        match self.backend.as_mut() {
            Some(backend) => backend.place(&transforms, &vertices),
            None => Ok(()),
        }
    }

    /// Whether a step's chosen points are traced by their plans on the
    /// backend, a ray at a time ([`AoBackend::cast_rays`]): where it casts
    /// single rays and ray reuse or early decisions ask for them.
    /// Otherwise a backend traces whole points.
    pub(super) fn planned_on_backend(&self) -> bool {
        self.backend.as_ref().is_some_and(|b| b.casts_rays())
            && ((self.config.ray_reuse && self.config.skip) || self.early_decisions().is_some())
    }

    /// Whether the pipeline keeps ray scores (ray reuse, early decisions):
    /// with the CPU tracer, or a backend that casts single rays.
    pub(super) fn keeps_ray_scores(&self) -> bool {
        self.backend.as_ref().is_none_or(|b| b.casts_rays())
    }

    /// Settles the points the last step traced and this one left alone
    /// (motion no longer reaches them; they wait neither for the budget
    /// nor for a view): nothing has changed what their last trace gave
    /// ([`compare_remembered`](Self::compare_remembered) keeps it), so that
    /// value is set, with no ray cast, where it is
    /// [`settle_steps`](super::PipelineConfig::settle_steps) or more from
    /// what clients hold. `now`: the points this step traced (the next
    /// step's last ones).
    pub(super) fn settle_left(&mut self, now: &[(usize, u32)]) -> Result<Settled, SceneError> {
        let mut out = Settled {
            touched: vec![false; self.instances.len()],
            updated: 0,
        };
        let steps = self.config.settle_steps;
        if steps == 0 {
            return Ok(out);
        }
        let mut keys: Vec<u64> = now.iter().map(|&(i, k)| key(i, k)).collect();
        keys.sort_unstable();
        let last = std::mem::replace(&mut self.last_traced, keys);
        for k in last {
            if self.last_traced.binary_search(&k).is_ok() || self.waiting.get(k).is_some() {
                continue;
            }
            let (i, p) = ((k >> 32) as usize, k as u32);
            let Some(s) = self.instances.get_mut(i) else {
                continue;
            };
            let at = p as usize;
            if s.pending.get(at).copied().unwrap_or(false) || at >= s.last_ao.len() {
                continue;
            }
            let q = s.last_ao[at];
            let (positions, normals) = s.stored();
            let (pos, nrm) = (positions[at], normals[at]);
            let held = s.table.sent(p, pos, nrm);
            if held.word.is_allocated() && held.word.fields().ao.abs_diff(q) >= steps {
                s.table.set_point(p, pos, nrm, dequantize_ao(q))?;
                s.buried.note_set(p);
                let stored = matches!(s.table.placement(p), psao_codec::Placement::Stored { .. });
                if let Some(t) = s.trend.get_mut(at) {
                    t.set_held(stored.then_some(q));
                }
                out.touched[i] = true;
                out.updated += 1;
            }
        }
        Ok(out)
    }

    /// Checks the last step's early decisions
    /// ([`PipelineConfig::early`](super::config::PipelineConfig::early)):
    /// traces each point that stopped early again, in full, in the scene
    /// as it is now (as that step left it), and compares it with what
    /// clients hold, as the thresholds would. A measurement for
    /// benchmarks and tests: it costs a full trace of those points, on
    /// the CPU tracer whatever the backend. Call it right after
    /// [`step`](Self::step).
    pub fn early_audit(&mut self) -> Result<super::early::EarlyAudit, SceneError> {
        if self.last_early.is_empty() {
            // Nothing stopped early (always so on a backend that casts no
            // single rays).
            return Ok(super::early::EarlyAudit::default());
        }
        let mut which: Vec<Vec<u32>> = vec![Vec::new(); self.instances.len()];
        for &k in &self.last_early {
            which[(k >> 32) as usize].push(k as u32);
        }
        let batch = self.batch(&which, false);
        let ao = self.config.ao;
        let full = self
            .tracer(false)
            .trace_ids(&batch.ids, &batch.points, &batch.normals, &ao)?;
        let th = self.config.thresholds;
        let mut audit = super::early::EarlyAudit {
            checked: batch.ids.len() as u64,
            ..Default::default()
        };
        for (sent, &value) in batch.sent.iter().zip(&full.ao) {
            let (full, held) = (quantize_ao(value), sent.word.fields().ao);
            audit.worst_steps = audit.worst_steps.max(full.abs_diff(held));
            // As `SentPoint::changed` would decide.
            if th.ao_changed(full, held) {
                audit.wrong += 1;
            }
        }
        Ok(audit)
    }

    /// The early decisions this pipeline makes: its
    /// [`PipelineConfig::early`](super::config::PipelineConfig::early)
    /// where they apply (ray scores kept, skipping on, settling off, at
    /// least 8 rays a point).
    pub(super) fn early_decisions(&self) -> Option<super::early::EarlyDecisions> {
        let c = &self.config;
        c.early
            .filter(|_| self.keeps_ray_scores() && c.skip && c.settle_steps == 0 && c.ao.rays >= 8)
    }

    /// Traces `batch` by `plans` ([`Cast`]: the values, and the rays the
    /// points known open did not cast), on the CPU (`tracer`) or, with
    /// none, on the backend, which casts the rays asked of it
    /// ([`AoBackend::cast_rays`]): a full trace casts every ray (and keeps
    /// the scores of a static instance's point), a partial one casts its
    /// needed rays over the kept scores. Each AO is the kept and new
    /// scores added in the tracer's order: what a full trace gives. With
    /// [`PipelineConfig::early`] a moving instance's point may stop early
    /// ([`early`](super::early)): its AO is then given as what clients
    /// hold, so nothing is sent, and it is listed in `last_early`. Both
    /// take the same decisions from the same scores
    /// ([`work`](super::work)).
    ///
    /// [`PipelineConfig::early`]: super::config::PipelineConfig::early
    /// [`AoBackend::cast_rays`]: super::backend::AoBackend::cast_rays
    fn trace_planned(
        &mut self,
        tracer: Option<&AoTracer>,
        batch: &Batch,
        plans: &[&Plan],
        changed: &[bool],
    ) -> Result<Cast, SceneError> {
        let ao = self.config.ao;
        ao.validate()?;
        let rays = ao.rays;
        let keep = self.config.ray_reuse && self.config.skip;
        let early = self.early_decisions();
        // Moving points' kept scores, taken out for the parallel trace.
        let mut taken: Vec<Option<Kept>> = Vec::new();
        if early.is_some() {
            taken = batch
                .owner
                .iter()
                .map(|&(i, k)| {
                    (self.instances[i].dynamic && changed[i])
                        .then(|| self.kept_scores.take(key(i, k)))
                        .flatten()
                })
                .collect();
        }
        let cache = &self.ray_cache;
        let instances = &self.instances;
        let th = self.config.thresholds;
        let moving = early.as_ref().map(|test| Moving {
            test,
            order: &self.ray_order,
            rot: super::early::rotation(ao.rays, self.frame),
            tolerance: th.ao_steps as f32 / 255.0,
            th: &th,
        });
        // Every ray, in order: what a full trace casts.
        let all: Vec<u32> = (0..rays).collect();
        let all = all.as_slice();
        // What point `b` casts (`drawn`: its rays, where the caller drew
        // them).
        let work_of = |b: usize, kept: Option<Kept>, drawn: Option<&Option<PointRays>>| {
            let (i, k) = batch.owner[b];
            let (id, p, n) = (batch.ids[b], batch.points[b], batch.normals[b]);
            let dynamic = instances[i].dynamic;
            // Every ray scores 1, known without casting one.
            let open = matches!(plans[b], Plan::Open);
            if let (Some(how), true) = (&moving, dynamic && changed[i]) {
                let has_rays = match drawn {
                    Some(r) => r.is_some(),
                    None => PointRays::new(id, p, n, &ao).is_some(),
                };
                let sent = &batch.sent[b];
                return PointWork::moving(b, kept, sent, n, (all, has_rays, open), how);
            }
            if !keep || dynamic {
                // Nothing kept (a moving instance's point).
                return PointWork::plain(b, all, open);
            }
            let ones = || vec![1.0f32; rays as usize];
            match (plans[b], cache.get(key(i, k))) {
                (Plan::Rays { need, .. }, Some(e)) if !open => {
                    PointWork::kept(b, e.scores.to_vec(), (all, Some(need)), false)
                }
                // A full trace (or, were its scores gone, a partial one).
                _ => PointWork::kept(b, ones(), (all, None), open),
            }
        };
        let mut done: Vec<Traced> = match tracer {
            Some(tracer) => {
                let work: Vec<(usize, Option<Kept>)> = morton_order(&batch.points)
                    .into_iter()
                    .map(|b| (b, taken.get_mut(b).and_then(Option::take)))
                    .collect();
                let mut done: Vec<Traced> = work
                    .into_par_iter()
                    .map(|(b, kept)| {
                        let (id, p, n) = (batch.ids[b], batch.points[b], batch.normals[b]);
                        let rays = PointRays::new(id, p, n, &ao);
                        let w = work_of(b, kept, Some(&rays));
                        let (i, k) = batch.owner[b];
                        let entry = if w.over_kept() {
                            cache.get(key(i, k))
                        } else {
                            None
                        };
                        // Nothing to hit: every ray scores 1.
                        let rays = rays.filter(|_| tracer.can_hit());
                        cast_on_cpu(tracer, w, rays, entry.map(|e| &e.rays[..]))
                    })
                    .collect();
                done.sort_unstable_by_key(|d| d.b);
                done
            }
            None => {
                let mut works: Vec<PointWork> = (0..batch.ids.len())
                    .map(|b| work_of(b, taken.get_mut(b).and_then(Option::take), None))
                    .collect();
                // Neither a tracer nor a backend: nothing to cast with (the
                // step passes one or the other).
                let Some(backend) = self.backend.as_mut() else {
                    return Err(SceneError::Backend {
                        backend: "cpu".into(),
                        reason: "no tracer and no backend to cast rays with".into(),
                    });
                };
                cast_on_backend(backend.as_mut(), batch, &mut works, &ao)?;
                works.into_iter().map(PointWork::finish).collect()
            }
        };
        let mut result = AoResult {
            ao: Vec::with_capacity(done.len()),
            rays: 0,
        };
        let mut rays_open = 0u64;
        let (mut eligible, mut eligible_rays) = (0u64, 0u64);
        for d in &mut done {
            result.ao.push(d.value);
            result.rays += d.cast;
            // A point known open casts none of the rays it was priced at.
            rays_open += d.priced.saturating_sub(d.cast);
            let (i, k) = batch.owner[d.b];
            if let Some(kept) = d.kept.take() {
                eligible += 1;
                eligible_rays += d.priced;
                if d.stopped {
                    self.last_early.push(key(i, k));
                }
                self.kept_scores.put(key(i, k), kept);
            }
            // Static points keep their scores for the next reach.
            if keep
                && !self.instances[i].dynamic
                && let Some(s) = d.scores.take()
            {
                let (id, p, n) = (batch.ids[d.b], batch.points[d.b], batch.normals[d.b]);
                self.ray_cache.store(key(i, k), &s, || {
                    PointRays::new(id, p, n, &ao).map_or_else(Vec::new, |r| {
                        (0..ao.rays)
                            .map(|j| {
                                let (d, len) = r.ray(j);
                                Vec3::from(d).extend(len)
                            })
                            .collect()
                    })
                });
            }
        }
        self.last_early.sort_unstable();
        if eligible > 0 {
            self.early_cost = eligible_rays as f64 / eligible as f64;
        }
        Ok(Cast {
            values: result,
            rays_open,
        })
    }

    /// The listed points of each instance in world space, with what clients
    /// hold of them (nothing with `force`).
    fn batch(&self, which: &[Vec<u32>], force: bool) -> Batch {
        let mut batch = self.batch_unheld(which);
        if force {
            batch.sent = vec![SentPoint::not_held(Vec3::ZERO); batch.ids.len()];
        } else {
            self.look_up_held(&mut batch);
        }
        batch
    }

    /// The listed points of every instance, as [`batch`](Self::batch)
    /// gives them, without what clients hold (`sent` empty).
    pub(super) fn batch_unheld(&self, which: &[Vec<u32>]) -> Batch {
        let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
        // (instance, point) of each traced point.
        let mut owner = Vec::new();
        let (mut moved_p, mut moved_n) = (Vec::new(), Vec::new());
        let mut base = 0u32;
        for (i, (s, list)) in self.instances.iter().zip(which).enumerate() {
            if list.is_empty() {
                base += s.points.len() as u32;
                continue;
            }
            let nm = normal_matrix(&s.transform);
            // Traced where the points are now.
            let (positions, normals) = s.now();
            ids.extend(list.iter().map(|&k| base + k));
            owner.extend(list.iter().map(|&k| (i, k)));
            // With many points waiting, gathering them is a good part of
            // the step: in parallel, in order.
            list.par_iter()
                .with_min_len(PAR_MIN)
                .map(|&k| {
                    let (p, n) = (positions[k as usize], normals[k as usize]);
                    (
                        s.transform.transform_point3(p),
                        (nm * n).normalize_or_zero(),
                    )
                })
                .unzip_into_vecs(&mut moved_p, &mut moved_n);
            pts.append(&mut moved_p);
            nrm.append(&mut moved_n);
            base += s.points.len() as u32;
        }
        Batch {
            ids,
            points: pts,
            normals: nrm,
            owner,
            sent: Vec::new(),
        }
    }

    /// Sets `batch.sent` to what clients hold of each of its points:
    /// compared where the table stores them (bind space for a bind-space
    /// instance), cells numbered across instances (instance i's after the
    /// pools of those before it).
    fn look_up_held(&self, batch: &mut Batch) {
        let mut cell_base = Vec::with_capacity(self.instances.len());
        let mut next = 0u32;
        for s in &self.instances {
            cell_base.push(next);
            next = next.saturating_add(s.table.def().cell_pool);
        }
        let instances = &self.instances;
        batch.sent = batch
            .owner
            .par_iter()
            .with_min_len(PAR_MIN)
            .map(|&(i, k)| {
                let s = &instances[i];
                let (stored_p, stored_n) = s.stored();
                let (p, n) = (stored_p[k as usize], stored_n[k as usize]);
                let mut held = s.table.sent(k, p, n);
                held.cell = held.cell.saturating_add(cell_base[i]);
                held
            })
            .collect();
    }

    /// Traces `batch` and keeps the points past the thresholds against what
    /// clients hold: on the backend when there is one (placed first),
    /// otherwise with `tracer`, or a tracer over the scene now.
    fn trace_batch(
        &mut self,
        tracer: Option<&AoTracer>,
        batch: &Batch,
        force: bool,
        th: &Thresholds,
    ) -> Result<ChangedPoints, SceneError> {
        let (ids, pts, nrm, sent) = (&batch.ids, &batch.points, &batch.normals, &batch.sent);
        let (ao, th) = (self.config.ao, *th);
        self.place_backend()?;
        Ok(match (&mut self.backend, tracer) {
            (Some(backend), _) => {
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
            s.buried.note_set(k);
            // A point the table dropped (no slot for it) is held by no
            // client, whatever its trend noted.
            if !matches!(s.table.placement(k), psao_codec::Placement::Stored { .. })
                && let Some(t) = s.trend.get_mut(k as usize)
            {
                t.set_held(None);
            }
        }
        Ok(())
    }
}

/// Casts point `w`'s rays on the CPU, a run at a time as it asks for
/// them: `rays` its rays against `tracer` (`None`: each scores 1, as
/// there is nothing to trace from or nothing to hit), `kept_rays` the ray
/// cache's kept directions and lengths, for a point casting some of its
/// rays over kept scores.
fn cast_on_cpu(
    tracer: &AoTracer,
    mut w: PointWork,
    rays: Option<PointRays>,
    kept_rays: Option<&[glam::Vec4]>,
) -> Traced {
    while !w.wants().is_empty() {
        w.take_each(|k| match &rays {
            // Nothing to trace from, or nothing to hit.
            None => 1.0,
            Some(r) => match kept_rays.and_then(|e| e.get(k as usize)) {
                Some(d) => r.score_along(tracer, Vec3A::from(d.truncate()), d.w),
                None => r.score(tracer, k),
            },
        });
    }
    w.finish()
}

/// Casts every point's rays of `works` on `backend`, a round at a time:
/// each round, the rays each point asks for next, together.
fn cast_on_backend(
    backend: &mut dyn AoBackend,
    batch: &Batch,
    works: &mut [PointWork],
    ao: &AoParams,
) -> Result<(), SceneError> {
    loop {
        let jobs: Vec<RayJob> = works
            .iter()
            .flat_map(|w| {
                w.wants().iter().map(|&ray| RayJob {
                    point: w.b as u32,
                    ray,
                })
            })
            .collect();
        if jobs.is_empty() {
            return Ok(());
        }
        let scores = backend.cast_rays(&batch.ids, &batch.points, &batch.normals, &jobs, ao)?;
        if scores.len() != jobs.len() {
            return Err(SceneError::Backend {
                backend: backend.name(),
                reason: format!("{} scores for {} rays", scores.len(), jobs.len()),
            });
        }
        let mut at = 0;
        for w in works.iter_mut() {
            let m = w.wants().len();
            if m > 0 {
                w.take(&scores[at..at + m]);
                at += m;
            }
        }
    }
}
