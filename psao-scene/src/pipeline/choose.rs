//! Choosing what a step traces: the step's points split into those
//! planned and those kept apart (a moving instance's, and waiting ones
//! that need a full trace or are planned late), the step's ray budget,
//! the budget's candidates, the plans of the chosen late points, and the
//! batch of the chosen ones (`select` in `budget` makes the choice).

use std::time::Instant;

use psao_codec::Thresholds;
use rayon::prelude::*;

use super::budget::{Candidate, REPLAN_WAITS, RayBudget, Waiting, due};
use super::config::{MoversWhole, PipelineConfig};
use super::dirty::{Batch, PAR_MIN, StepMotion};
use super::loops::{LoopMemory, Moment};
use super::plan::Plan;
use super::ray_cache::key;
use super::reach::{MotionBoxes, ReachQuery, reached_rays};
use super::stage::Stage;
use super::{InstanceState, Pipeline};
use crate::trace::ao::{AoTracer, PointRays};

/// A step's budget candidates: the planned points that trace and the
/// points apart (waiting ones, and a moving instance's), merged in
/// (instance, point) order.
pub(super) struct Candidates {
    /// The batch index of each planned candidate.
    pub at: Vec<usize>,
    /// Per planned candidate, whether it really waited (a mover's point
    /// traced every step, or one of a part traced whole this step,
    /// counts as overdue without having waited; with ray reuse a mover's
    /// points wait apart).
    pub waited_really: Vec<bool>,
    /// The same per point apart: a mover's point traced every step, or
    /// one of a part traced whole this step (a mover's, or one planned
    /// late), has not really waited (as it would not have, planned with
    /// the others).
    pub apart_really: Vec<bool>,
    /// Per planned candidate, whether the loop memory verified it
    /// (`Remembered::verified`): it enters the budget as one that has not
    /// waited, and if not chosen its wait starts again.
    pub verified_at: Vec<bool>,
    /// The same per point apart.
    pub verified_apart: Vec<bool>,
    /// Each candidate in merged order: (apart, index into `at` or into
    /// the points apart).
    pub merged: Vec<(bool, usize)>,
    /// The candidates in merged order.
    pub all: Vec<Candidate>,
    /// Per instance held whole under the budget
    /// ([`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)):
    /// `Some(true)` traced whole this step, `Some(false)` held, its points
    /// waiting together; `None` for the others.
    pub whole: Vec<Option<bool>>,
    /// Planned points that motion reaches with no ray (nothing to trace).
    pub unreached: u64,
}

/// Why a point of a step is kept apart from planning (its plan is known
/// without planning it; see [`Pipeline::split_waiting`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum ApartAs {
    /// A waiting point of an instance that did not move, with no kept
    /// scores, flagged as needing a full trace: a full trace.
    Full,
    /// A waiting point of an instance that did not move, planned late:
    /// the rays of it known stale (what it costs until it is planned).
    Late(u32),
    /// A point of an instance that moved this step (waiting, or reached
    /// now), with ray reuse: a full trace, as `plan` plans every such
    /// point (with early decisions, one that may stop early).
    Moving,
}

/// The points of a step kept apart from planning (see
/// [`Pipeline::split_waiting`]), ascending by key.
#[derive(Default)]
pub(super) struct Apart {
    /// Their keys.
    pub keys: Vec<u64>,
    /// Per point, why it is apart.
    pub how: Vec<ApartAs>,
}

impl Apart {
    /// What point `j` costs the budget of a point's `rays` until it is
    /// planned, and counts as reached (before early decisions).
    pub fn cost(&self, j: usize, rays: u32) -> u32 {
        match self.how.get(j) {
            Some(&ApartAs::Late(n)) => n,
            _ => rays,
        }
    }
}

/// What ranking a candidate reads of the pipeline: borrowed apart from
/// it, so that threads can share it (a pipeline's backend need not be
/// `Sync`).
struct Ranking<'a> {
    /// The instances (their trends and heat).
    instances: &'a [InstanceState],
    /// The waiting points.
    waiting: &'a Waiting,
    /// The pipeline's configuration.
    config: &'a PipelineConfig,
    /// Per instance, the part traced over several steps, if any
    /// ([`Stage`]).
    stages: &'a [Option<Stage>],
    /// Per instance, whether it was placed this step (a placed part's
    /// stage is dropped).
    placed: &'a [bool],
    /// The step's number.
    step: u64,
    /// The loop memory, if any, the step's moment of the loop, and the
    /// thresholds a remembered AO is compared with (the send threshold,
    /// or the settling one where settling may send a point).
    loop_memory: Option<(&'a LoopMemory, Moment, Thresholds)>,
}

/// What the loop memory says of a candidate at a step (all false without
/// a memory, or for a point stored as posed, whose position alone may
/// send it).
#[derive(Clone, Copy, Default)]
struct Remembered {
    /// Its AO traced at this moment of an earlier round, or at a pose that
    /// verifies this step's, would not be sent against what clients hold:
    /// it probably has nothing to send, and ranks as one without a trend
    /// (urgency 0), by the share of its rays motion reached.
    nothing_to_send: bool,
    /// Its AO traced at a pose that verifies this step's (the same time
    /// within the loop, to the tolerance, no jump between) would not be
    /// sent: clients are not behind a full re-trace now. (Applied only to
    /// a point that waits as itself, not one of a part traced or held
    /// whole, whose transform clients hold need not be the one posed
    /// now.)
    verified: bool,
}

impl Ranking<'_> {
    /// The age and cost a candidate, point `key` costing `cost` rays,
    /// enters the budget with: a mover's point traced every step it moves
    /// (`every_step`), or one of a part traced whole this step (`whole`
    /// `Some(true)`), as one that waited its longest, the `bound`; one of
    /// a part held whole (`Some(false)`) as one that fits no budget and is
    /// not due (a held point's cost fits no budget below `u32::MAX` rays;
    /// a part that cost as much would fit such a budget whole); any other
    /// as it waited, or, where the loop memory verifies it (`verified`,
    /// [`Remembered::verified`]), as one that has not waited (its wait
    /// starts again: the third value). A point of a part traced whole
    /// whose stage traced it already costs nothing more.
    fn age_and_cost(
        &self,
        key: u64,
        (every_step, whole, verified): (bool, Option<bool>, bool),
        cost: u32,
        bound: u32,
    ) -> (u32, u32, bool) {
        // Traced by a stage that ends now as planned (one placed, or
        // made to end early at another pose, is dropped: traced now).
        let staged = || {
            let i = (key >> 32) as usize;
            let (Some(Some(stage)), Some(s)) = (self.stages.get(i), self.instances.get(i)) else {
                return false;
            };
            !self.placed.get(i).copied().unwrap_or(false)
                && stage.ends_as_planned(self.step, &s.transform)
                && stage.traced(key as u32).is_some()
        };
        match (every_step, whole) {
            (false, Some(true)) if staged() => (bound, 0, false),
            (true, _) | (false, Some(true)) => (bound, cost, false),
            (false, Some(false)) => (0, u32::MAX, false),
            (false, None) => match self.waiting.get(key) {
                Some(_) if verified => (0, cost, true),
                w => (w.map_or(0, |w| w.0), cost, false),
            },
        }
    }

    /// What the loop memory (`loops`) says of point `key` at this step:
    /// one look-up.
    fn remembered(&self, key: u64) -> Remembered {
        let none = Remembered::default();
        let Some((memory, at, th)) = self.loop_memory else {
            return none;
        };
        let Some(s) = self.instances.get((key >> 32) as usize) else {
            return none;
        };
        // Not a point stored as posed, whose position alone may send it.
        if !(s.positions.is_empty() || s.bind) {
            return none;
        }
        let held = s.trend.get(key as u32 as usize).and_then(|t| t.held());
        let (Some(held), Some(r)) = (held, memory.recall(key, at)) else {
            return none;
        };
        let unsent = !th.ao_changed(r.ao, held);
        Remembered {
            nothing_to_send: unsent && (r.earlier || r.verifies),
            verified: unsent && r.verifies,
        }
    }

    /// Point `key`'s candidate: it costs `cost` rays, motion reached
    /// `reached` of its rays, it has waited `age` steps, under `bound`;
    /// `unsent`: the loop memory says it has nothing to send
    /// ([`Remembered::nothing_to_send`]).
    fn candidate(
        &self,
        key: u64,
        (cost, reached, age): (u32, u32, u32),
        bound: u32,
        unsent: bool,
    ) -> Candidate {
        let rays = self.config.ao.rays.max(1);
        let urgency = if unsent {
            0.0
        } else {
            self.urgency((key >> 32) as usize, key as u32, age, reached >= rays)
        };
        Candidate {
            cost,
            reached: reached as f32 / rays as f32,
            age,
            due: due(key, bound),
            urgency,
        }
    }

    /// A point's urgency for the budget (`Candidate::urgency`, from its
    /// `Trend`) once it has waited `age` steps; 0 without a budget (no
    /// trends kept). A point traced in full (`full`: its share reached is
    /// 1 whatever motion does, so reach tells nothing of it) of a rigid
    /// instance that can move is at least as urgent as the fastest pace
    /// near it (its `Heat` cell's, see `trend`) makes it.
    fn urgency(&self, i: usize, k: u32, age: u32, full: bool) -> f32 {
        let Some(s) = self.instances.get(i) else {
            return 0.0;
        };
        let threshold = self.config.thresholds.ao_steps.max(1) as f32;
        let trend = s.trend.get(k as usize);
        let own = trend.map_or(0.0, |t| t.urgency(age, self.config.thresholds.ao_steps));
        // Not a deforming instance's points: its pose changes them all
        // at once, so a neighbour's pace says nothing of a front sweeping
        // over it, and its points' own paces say how fast they move. Not
        // a static instance's: reach knows what motion does to its rays.
        // (BENCHMARKS.md, the ray budget's eighth part, measures both.)
        if !(full && s.keeps_heat()) {
            return own;
        }
        let near = s
            .points
            .positions
            .get(k as usize)
            .map_or(0.0, |&p| s.heat.pace(p, self.step as u32));
        own.max(near * (age as f32 + 1.0) / threshold)
    }
}

impl Pipeline {
    /// Of the `chosen` points (the chosen batch, planned and apart, with
    /// their `plans`), those traced in full whose last AO was
    /// open (their last trace's, or what clients held when it stopped
    /// early) and whose rays can hit nothing
    /// ([`PointRays::surely_open`] against `tracer`, this step's scene):
    /// planned again as `open` ([`Plan::Open`]), traced without casting a
    /// ray.
    /// Found after choosing, so that the test, a good part of a trace, is
    /// spent on points traced only, and only where the last trace came
    /// out open: a point that was shaded seldom has nothing within reach.
    /// The budget's choices stand (such a point was chosen at the cost of
    /// its rays, and with early decisions decides on scores of 1, as its
    /// rays would): frames are the same as with every ray cast, and the
    /// step takes less time. Not the points of the instances `staged`,
    /// whose stage ends this step and gives their AO whatever their plan.
    /// With [`PipelineConfig::skip`] and [`PipelineConfig::skip_open`].
    ///
    /// [`PipelineConfig::skip`]: super::config::PipelineConfig::skip
    /// [`PipelineConfig::skip_open`]: super::config::PipelineConfig::skip_open
    pub(super) fn known_open<'p>(
        &self,
        tracer: &AoTracer,
        (chosen, staged): (&Batch, &[usize]),
        plans: &mut [&'p Plan],
        open: &'p Plan,
    ) {
        if !(self.config.skip && self.config.skip_open) {
            return;
        }
        let ao = self.config.ao;
        let todo: Vec<usize> = (0..chosen.ids.len())
            .filter(|&b| {
                let (i, k) = chosen.owner[b];
                matches!(plans[b], Plan::Full { .. })
                    && !staged.contains(&i)
                    && self.instances[i].last_ao.get(k as usize) == Some(&u8::MAX)
            })
            .collect();
        let found: Vec<bool> = todo
            .par_iter()
            .map(|&b| {
                PointRays::new(chosen.ids[b], chosen.points[b], chosen.normals[b], &ao)
                    .is_some_and(|r| r.surely_open(tracer))
            })
            .collect();
        for (&b, _) in todo.iter().zip(&found).filter(|(_, o)| **o) {
            plans[b] = open;
        }
    }

    /// Adds the waiting points to the step's `lists` (ascending, each
    /// once), except those whose plan is known without planning them,
    /// which are returned apart, and takes a moving instance's listed
    /// points out of `lists`: every point of an instance that moved
    /// (with ray reuse: `plan` traces each such point in full), waiting
    /// or reached now; and, of instances that did not move, those that
    /// need a full trace and have no kept scores (every ray, all
    /// reached), and those planned late (the rays known stale, until the
    /// budget takes them and [`plan_late`](Self::plan_late) plans them),
    /// except those that stopped early last step (traced in full, as
    /// `plan` plans them). With many points waiting, or a deforming
    /// instance of many points, that is most of them. Also returns which
    /// instances have points to trace or waiting.
    pub(super) fn split_waiting(
        &mut self,
        lists: &mut [Vec<u32>],
        motion: &StepMotion,
    ) -> (Apart, Vec<bool>) {
        let keys = self.waiting.keys();
        let reuse = self.config.ray_reuse && self.config.skip;
        let cache = reuse && self.keeps_ray_scores();
        let (waiting, ray_cache, rested) = (&self.waiting, &self.ray_cache, &self.early_rested);
        // Whether instance `i` moved this step (`true` for one unknown, so
        // that it is planned).
        let moved = |i: usize| motion.changed.get(i).copied().unwrap_or(true);
        // Whether its points wait apart as movers: known to `plan`.
        let moving = |i: usize| reuse && motion.changed.get(i).copied().unwrap_or(false);
        // `None`: planned with the others.
        let apart_as = |key: u64| -> Option<ApartAs> {
            let (_, full) = waiting.get(key)?;
            let i = (key >> 32) as usize;
            if moving(i) {
                return Some(ApartAs::Moving);
            }
            if moved(i) {
                return None;
            }
            let entry = if cache { ray_cache.get(key) } else { None };
            match entry {
                None => full.then_some(ApartAs::Full),
                // As `plan` plans it: a point that stopped early last
                // step is traced in full.
                Some(e) => (waiting.late_since(key).is_some()
                    && rested.binary_search(&key).is_err())
                .then(|| ApartAs::Late(e.stale.count())),
            }
        };
        // Tens of thousands may wait: looked at in parallel.
        let how: Vec<Option<ApartAs>> = keys
            .par_iter()
            .with_min_len(PAR_MIN)
            .map(|&k| apart_as(k))
            .collect();
        let mut apart = Apart::default();
        let mut touched: Vec<bool> = lists.iter().map(|w| !w.is_empty()).collect();
        for (&k, how) in keys.iter().zip(how) {
            let (i, p) = ((k >> 32) as usize, k as u32);
            if let Some(t) = touched.get_mut(i) {
                *t = true;
            }
            if let Some(how) = how {
                apart.keys.push(k);
                apart.how.push(how);
            } else if let Some(l) = lists.get_mut(i) {
                l.push(p);
            }
        }
        if (0..lists.len()).any(|i| moving(i) && !lists[i].is_empty()) {
            apart = with_movers(apart, lists, moving);
        }
        for (i, l) in lists.iter_mut().enumerate() {
            // Two ascending runs: the stable sort merges them.
            l.sort();
            l.dedup();
            // Less the points motion reached that wait apart (this
            // instance's run of the ascending keys), in one walk.
            let i = i as u64;
            let from = apart.keys.partition_point(|&k| k >> 32 < i);
            let to = from + apart.keys[from..].partition_point(|&k| k >> 32 == i);
            let mut mine = apart.keys[from..to].iter().map(|&k| k as u32).peekable();
            if mine.peek().is_some() {
                l.retain(|&p| {
                    while mine.next_if(|&q| q < p).is_some() {}
                    mine.peek() != Some(&p)
                });
            }
        }
        (apart, touched)
    }

    /// The rays this step may cast (`None`: no limit). An automatic budget
    /// gets what is left of its share of the period once the step so far
    /// (from `started` on, planning included) and what it does besides
    /// casting from here on (as in the last steps) are paid for.
    pub(super) fn step_budget(&self, motion: &StepMotion, started: Instant) -> Option<u64> {
        match self.config.budget {
            RayBudget::Unlimited => None,
            RayBudget::Rays(n) => Some(n),
            RayBudget::Auto { share } => {
                // What is left of the share once the step so far, the
                // planning and what the step does besides casting from
                // here on (as it took in the last steps) are paid for.
                let left = share as f64 * motion.period
                    - motion.elapsed.as_secs_f64()
                    - started.elapsed().as_secs_f64()
                    - self.tail_s;
                Some(if self.ray_ns > 0.0 {
                    (left.max(0.0) * 1e9 / self.ray_ns) as u64
                } else {
                    u64::MAX
                })
            }
        }
    }

    /// The budget's candidates of a step: the points of `batch` their
    /// `plans` trace, each costing the rays it casts, and the points
    /// `apart` (a full trace each, a mover's with early decisions at what
    /// such points cast on average, or the rays known stale of one
    /// planned late), merged in (instance, point) order so that `select`
    /// breaks ties by position.
    pub(super) fn candidates(
        &self,
        batch: &Batch,
        plans: &[Plan],
        apart: &Apart,
        motion: &StepMotion,
        bound: u32,
        budget: Option<u64>,
    ) -> Candidates {
        let rays = self.config.ao.rays;
        let whole = self.whole_movers(batch, plans, apart, motion, bound, budget);
        let rank = Ranking {
            instances: &self.instances,
            waiting: &self.waiting,
            config: &self.config,
            stages: &self.stages,
            placed: &motion.placed,
            step: self.frame,
            loop_memory: self.loop_rule(),
        };
        // A moving point that may stop early costs what such points cast
        // on average.
        let (moving_cost, max_stops) = match self.early_decisions() {
            Some(e) => (
                (self.early_cost.ceil() as u32).clamp(1, rays.max(1)),
                e.max_stops,
            ),
            None => (rays, 0),
        };
        let (instances, kept) = (&self.instances, &self.kept_scores);
        let every_step_movers = self.config.movers_every_step;
        // Each planned point's candidate, and whether it really waited (a
        // mover's point traced every step counts as overdue without
        // having waited); `None` where motion reached no ray. In
        // parallel: tens of thousands may wait.
        let planned: Vec<Option<(Candidate, bool, bool)>> = (plans.par_iter().enumerate())
            .with_min_len(PAR_MIN)
            .map(|(b, plan)| {
                let reached = match plan {
                    Plan::Skip => return None,
                    Plan::Full { reached } => *reached,
                    // (Found only after choosing: see `known_open`.)
                    Plan::Open => 0,
                    Plan::Rays { reached, .. } => reached.count(),
                };
                let cost = plan.cost(rays);
                let (i, k) = batch.owner[b];
                // A moving point that may stop early costs what such
                // points cast on average; one that will trace in full
                // (nothing kept yet, or stopped its most times in a row)
                // all its rays.
                let cost = match plan {
                    Plan::Full { .. }
                        if instances[i].dynamic
                            && motion.changed[i]
                            && kept.may_stop(key(i, k), max_stops) =>
                    {
                        moving_cost
                    }
                    _ => cost,
                };
                // A mover's own point traced every step it moves, if so
                // configured (see `age_and_cost`); it has not really
                // waited.
                let every_step = every_step_movers && motion.changed[i];
                let m = rank.remembered(key(i, k));
                let (age, cost, verified) =
                    rank.age_and_cost(key(i, k), (every_step, whole[i], m.verified), cost, bound);
                let really = !every_step && whole[i] != Some(true);
                let c = rank.candidate(key(i, k), (cost, reached, age), bound, m.nothing_to_send);
                Some((c, really, verified))
            })
            .collect();
        let (mut at, mut cands, mut waited_really) = (Vec::new(), Vec::new(), Vec::new());
        let mut verified_at = Vec::new();
        let mut unreached = 0u64;
        for (b, p) in planned.into_iter().enumerate() {
            match p {
                None => unreached += 1,
                Some((c, really, verified)) => {
                    at.push(b);
                    cands.push(c);
                    waited_really.push(really);
                    verified_at.push(verified);
                }
            }
        }
        // The points apart: a full trace each (a mover's as a planned
        // one's), or the rays known stale of one planned late (all
        // counted as reached).
        let (apart_cands, (apart_really, verified_apart)): (
            Vec<Candidate>,
            (Vec<bool>, Vec<bool>),
        ) = (apart.keys.par_iter().enumerate())
            .with_min_len(PAR_MIN)
            .map(|(j, &k)| {
                let i = (k >> 32) as usize;
                let whole = whole.get(i).copied().flatten();
                let reached = apart.cost(j, rays);
                let (cost, every_step, really) = match apart.how[j] {
                    ApartAs::Moving => {
                        let cost = if instances.get(i).is_some_and(|s| s.dynamic)
                            && kept.may_stop(k, max_stops)
                        {
                            moving_cost
                        } else {
                            reached
                        };
                        let every_step = every_step_movers;
                        (cost, every_step, !every_step && whole != Some(true))
                    }
                    ApartAs::Full => (reached, false, true),
                    ApartAs::Late(_) => (reached, false, whole != Some(true)),
                };
                let m = rank.remembered(k);
                let (age, cost, verified) =
                    rank.age_and_cost(k, (every_step, whole, m.verified), cost, bound);
                let c = rank.candidate(k, (cost, reached, age), bound, m.nothing_to_send);
                (c, (really, verified))
            })
            .unzip();
        let apart = &apart.keys;
        // Both in (instance, point) order, merged so (`select` breaks ties
        // by position): (apart, index) of each.
        let mut merged = Vec::with_capacity(at.len() + apart.len());
        let (mut x, mut y) = (0, 0);
        while x < at.len() || y < apart.len() {
            let planned_first = y >= apart.len()
                || (x < at.len() && {
                    let (i, k) = batch.owner[at[x]];
                    key(i, k) < apart[y]
                });
            if planned_first {
                merged.push((false, x));
                x += 1;
            } else {
                merged.push((true, y));
                y += 1;
            }
        }
        let all: Vec<Candidate> = merged
            .iter()
            .map(|&(a, j)| if a { apart_cands[j] } else { cands[j] })
            .collect();
        Candidates {
            at,
            waited_really,
            apart_really,
            verified_at,
            verified_apart,
            merged,
            all,
            whole,
            unreached,
        }
    }

    /// The loop memory, if any, with this step's moment of the loop and
    /// the thresholds a remembered AO is compared with: the send
    /// threshold, or the settling one where settling may send a point
    /// ([`PipelineConfig::settle_steps`]). None where every trace is sent
    /// (a negative position quantum), where nothing can be predicted.
    fn loop_rule(&self) -> Option<(&LoopMemory, Moment, Thresholds)> {
        let memory = self.loop_memory.as_ref()?;
        let mut th = self.config.thresholds;
        if th.position_quanta < 0.0 {
            return None;
        }
        if let Some(settle) = self.config.settle_steps.checked_sub(1) {
            th.ao_steps = th.ao_steps.min(settle);
        }
        Some((memory, self.loop_moment()?, th))
    }

    /// Which rigid movers a step traces whole and which it holds, under
    /// [`PipelineConfig::movers_whole`](super::config::PipelineConfig::movers_whole)
    /// and a `budget` (see [`Candidates::whole`]): every one with `On`;
    /// with `Auto` those held already and, as half the budget affords,
    /// those whose AO depends on their pose with no point due now
    /// ([`Pipeline::auto_held`]). A part whose transform
    /// is at stake (it moved, or clients do not hold its transform yet),
    /// with points to trace that cost at most `max_wait` budgets (or held
    /// already), is traced whole when they fit in the budget, when one of
    /// them has waited its due under `bound`, when the part has been held
    /// for [`max_wait`](super::config::PipelineConfig::max_wait) steps (not
    /// the bound demand may have raised: a part held longer would lag its
    /// motion by as much), or when it was placed this step; else held. A
    /// part traced over several steps ([`Stage`]) is traced whole (the
    /// stage ends) in the step it was planned to end in, or as the rules
    /// above say.
    fn whole_movers(
        &self,
        batch: &Batch,
        plans: &[Plan],
        apart: &Apart,
        motion: &StepMotion,
        bound: u32,
        budget: Option<u64>,
    ) -> Vec<Option<bool>> {
        let n = self.instances.len();
        let mode = self.config.movers_whole;
        let Some(budget) =
            budget.filter(|_| mode != MoversWhole::Off && !self.config.movers_every_step)
        else {
            return vec![None; n];
        };
        let rays = self.config.ao.rays;
        let mut cost = vec![0u64; n];
        // Whether one of its points has waited its due: then the part is
        // traced whole now, so that none waits past the bound.
        let mut due_now = vec![false; n];
        let overdue = |k: u64| self.waiting.get(k).is_some_and(|w| w.0 >= due(k, bound));
        for (b, plan) in plans.iter().enumerate() {
            let (i, p) = batch.owner[b];
            cost[i] += u64::from(plan.cost(rays));
            due_now[i] |= !matches!(plan, Plan::Skip) && overdue(key(i, p));
        }
        for (j, &k) in apart.keys.iter().enumerate() {
            let i = (k >> 32) as usize;
            if let Some(c) = cost.get_mut(i) {
                *c += u64::from(apart.cost(j, rays));
                due_now[i] |= overdue(k);
            }
        }
        // Traced whole at least every `max_wait` steps, a part costs at
        // most a budget a step on average if its points cost at most
        // `max_wait` budgets; a bigger one waits point by point. A part
        // held already stays held until it is traced whole, whatever this
        // step's budget.
        let candidate: Vec<bool> = (self.instances.iter().enumerate())
            .map(|(i, s)| {
                let at_stake = motion.changed.get(i).copied().unwrap_or(false)
                    || s.sent_seq != s.transform_seq
                    || s.held_steps > 0;
                s.rigid_mover()
                    && at_stake
                    && cost[i] > 0
                    && (s.held_steps > 0
                        || cost[i] <= budget.saturating_mul(u64::from(self.config.max_wait)))
            })
            .collect();
        // `On` holds every candidate; `Auto` some of them.
        let held_whole = match mode {
            MoversWhole::Auto => self.auto_held(&candidate, &cost, &due_now, budget),
            _ => candidate,
        };
        self.instances
            .iter()
            .enumerate()
            .map(|(i, s)| {
                held_whole[i].then(|| {
                    let fits = match self.stages.get(i).and_then(Option::as_ref) {
                        // A stage ends in the step it was planned to.
                        Some(stage) => self.frame >= stage.ends_at,
                        None => cost[i] <= budget,
                    };
                    due_now[i]
                        || fits
                        || s.held_steps.saturating_add(1) >= self.config.max_wait
                        || motion.placed.get(i).copied().unwrap_or(false)
                })
            })
            .collect()
    }

    /// Of the `candidate` parts (rigid movers at stake, with points to
    /// trace, that a budget may hold whole), those [`MoversWhole::Auto`]
    /// holds whole this step, given each one's `cost` in rays, whether
    /// one of its points is due now, and the step's `budget`: those held
    /// already (until they are traced), then, most dependent on their pose
    /// first, those whose AO depends on their pose, that do not turn in
    /// place (their occlusion stays with their surroundings) and none of
    /// whose points is due now (else it would be traced whole at once,
    /// whatever the budget), as long as the held ones together cost at most half a
    /// budget a step (each its cost over `max_wait` steps): a scene of many
    /// moving parts holds only those it can afford to trace whole.
    fn auto_held(
        &self,
        candidate: &[bool],
        cost: &[u64],
        due_now: &[bool],
        budget: u64,
    ) -> Vec<bool> {
        let per_step = |i: usize| cost[i].div_ceil(u64::from(self.config.max_wait.max(1)));
        let already = |i: usize| {
            candidate[i]
                && (self.instances[i].held_steps > 0
                    || self.stages.get(i).is_some_and(Option::is_some))
        };
        let mut held: Vec<bool> = (0..self.instances.len()).map(already).collect();
        let mut spent: u64 = (0..held.len()).filter(|&i| held[i]).map(per_step).sum();
        let mut wanted: Vec<(f32, usize)> = (self.instances.iter().enumerate())
            .filter(|&(i, s)| {
                candidate[i]
                    && !held[i]
                    && s.pose.depends()
                    && !s.pose.turns_in_place()
                    && !due_now[i]
            })
            .map(|(i, s)| (s.pose.share().unwrap_or(0.0), i))
            .collect();
        wanted.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        for (_, i) in wanted {
            if spent + per_step(i) <= budget / 2 {
                spent += per_step(i);
                held[i] = true;
            }
        }
        held
    }

    /// The batch of the chosen points, planned (`take`, indices into
    /// `batch`) and apart (`take_apart`, keys), in (instance, point) order,
    /// with each one's plan (for those apart, the one `late` gives, by
    /// ascending key, else `full`); what clients hold is not looked up
    /// yet.
    pub(super) fn chosen_batch<'p>(
        &self,
        (batch, plans): (&Batch, &'p [Plan]),
        take: &[usize],
        take_apart: &[u64],
        (late, full): (&'p [(u64, Plan)], &'p Plan),
    ) -> (Batch, Vec<&'p Plan>) {
        if take_apart.is_empty() {
            let sub_plans: Vec<&Plan> = take.iter().map(|&b| &plans[b]).collect();
            (batch.select(take), sub_plans)
        } else {
            let mut chosen_lists = vec![Vec::new(); self.instances.len()];
            for (i, p) in take
                .iter()
                .map(|&b| batch.owner[b])
                .chain(take_apart.iter().map(|&k| ((k >> 32) as usize, k as u32)))
            {
                chosen_lists[i].push(p);
            }
            for l in &mut chosen_lists {
                l.sort();
            }
            let sub = self.batch_unheld(&chosen_lists);
            // Both ascending: a planned point is the next of `take` or else
            // one apart.
            let mut next = take.iter().peekable();
            let sub_plans: Vec<&Plan> = sub
                .owner
                .iter()
                .map(|&o| match next.peek() {
                    Some(&&b) if batch.owner[b] == o => {
                        next.next();
                        &plans[b]
                    }
                    _ => late
                        .binary_search_by_key(&key(o.0, o.1), |l| l.0)
                        .map_or(full, |at| &late[at].1),
                })
                .collect();
            (sub, sub_plans)
        }
    }

    /// Keeps the boxes of what moved in this step (`motion`) for the
    /// points planned late, with those of as many steps before as a point
    /// may wait (the bound's limit and its spread).
    pub(super) fn remember_motion(&mut self, motion: &StepMotion) {
        if !self.config.plan_late {
            return;
        }
        let keep = self.config.max_wait_limit.max(self.config.max_wait) as usize + 2;
        while self.moved.len() >= keep {
            self.moved.pop_front();
        }
        self.moved
            .push_back((self.frame as u32, motion.boxes.clone()));
    }

    /// Plans the `chosen` candidates planned late, which wait `apart`
    /// (one whose instance moved waits apart as a mover's point, traced
    /// in full; one in the step's batch has a reason for the full trace
    /// `plan` gave it: it stopped early last step, or its scores are
    /// gone): until now each cost the rays known stale; now it
    /// also needs every ray of it that what moved reached in the steps
    /// since it was last planned (tested against their boxes,
    /// [`MotionBoxes::joined`], with its kept scores: what planning each
    /// step would have found, and maybe a ray more where boxes were
    /// merged). A point whose steps are no longer all remembered is
    /// traced in full. The budget chose it at its earlier cost: where the
    /// rays the chosen points now need pass `budget` (`spent` as chosen),
    /// the late points not overdue under `bound` are put back to wait,
    /// lowest priority first, until they fit: planned in this step, the
    /// rays of their new plan marked stale (or, where that plan is a full
    /// trace, their scores forgotten: they then wait for one). Returns the
    /// plans of the chosen ones (ascending keys).
    pub(super) fn plan_late(
        &mut self,
        apart: &Apart,
        cands: &Candidates,
        chosen: &mut [bool],
        (budget, spent, bound): (Option<u64>, u64, u32),
    ) -> Vec<(u64, Plan)> {
        if !self.config.plan_late {
            return Vec::new();
        }
        let ao = self.config.ao;
        // (merged index, key, the step it was last planned in), in merged
        // order, so ascending keys.
        let late: Vec<(usize, u64, u32)> = (cands.merged.iter().zip(chosen.iter()))
            .enumerate()
            .filter(|&(_, (&(is_apart, j), &c))| {
                c && is_apart && matches!(apart.how.get(j), Some(ApartAs::Late(_)))
            })
            .filter_map(|(m, (&(_, j), _))| {
                let k = apart.keys[j];
                self.waiting.late_since(k).map(|since| (m, k, since))
            })
            .collect();
        if late.is_empty() {
            return Vec::new();
        }
        // Where they lie: their batch, in the same order.
        let mut lists = vec![Vec::new(); self.instances.len()];
        for &(_, k, _) in &late {
            if let Some(l) = lists.get_mut((k >> 32) as usize) {
                l.push(k as u32);
            }
        }
        let lying = self.batch_unheld(&lists);
        let now = self.frame as u32;
        // The boxes of the steps after each `since`, up to this one, once
        // for all the points planned in that step (`None`: not all of
        // those steps are remembered).
        let mut sinces: Vec<u32> = late.iter().map(|l| l.2).collect();
        sinces.sort_unstable();
        sinces.dedup();
        let moved = &self.moved;
        let boxes: Vec<Option<MotionBoxes>> = sinces
            .iter()
            .map(|&since| {
                let steps = now.wrapping_sub(since) as usize;
                let first = moved.len().checked_sub(steps)?;
                (moved.get(first).map(|m| m.0) == Some(since.wrapping_add(1)))
                    .then(|| MotionBoxes::joined(moved.range(first..).map(|m| &m.1)))
            })
            .collect();
        let cache = &self.ray_cache;
        let full = Plan::Full { reached: ao.rays };
        let planned: Vec<Plan> = (late.par_iter().enumerate())
            .map(|(b, &(_, k, since))| {
                // (Every point has its place in `lying`, whose instances
                // are the pipeline's.)
                let (Some(&(i, p)), Some(e)) = (lying.owner.get(b), cache.get(k)) else {
                    return full.clone();
                };
                let Some(Some(boxes)) = sinces.binary_search(&since).ok().map(|at| &boxes[at])
                else {
                    return full.clone();
                };
                let Some(r) = (key(i, p) == k)
                    .then(|| PointRays::new(lying.ids[b], lying.points[b], lying.normals[b], &ao))
                    .flatten()
                else {
                    return full.clone();
                };
                let reached = reached_rays(
                    &r,
                    ao.rays,
                    boxes,
                    ao.estimator,
                    ao.radius,
                    ReachQuery {
                        dirs: Some(&e.rays),
                        scores: Some(&e.scores),
                        ..ReachQuery::default()
                    },
                );
                let mut need = reached.clone();
                need.union(&e.stale);
                Plan::Rays { need, reached }
            })
            .collect();
        let mut total = spent;
        // Those not overdue, which may go back: (merged index, index into
        // `late`).
        let mut back = Vec::new();
        for (n, (&(m, _, _), p)) in late.iter().zip(&planned).enumerate() {
            total = total - u64::from(cands.all[m].cost) + u64::from(p.cost(ao.rays));
            if !cands.all[m].overdue(bound) {
                back.push((m, n));
            }
        }
        if let Some(budget) = budget.filter(|&b| total > b) {
            // Lowest priority first (ties: the later in merged order).
            back.sort_by(|&(x, _), &(y, _)| {
                let (px, py) = (cands.all[x].priority(), cands.all[y].priority());
                px.total_cmp(&py).then(y.cmp(&x))
            });
            for (m, n) in back {
                if total <= budget {
                    break;
                }
                chosen[m] = false;
                let k = late[n].1;
                total -= u64::from(planned[n].cost(ao.rays));
                self.waiting.replanned(k, now);
                match &planned[n] {
                    Plan::Rays { reached, .. } => {
                        self.ray_cache.mark_stale(k, reached);
                    }
                    // Its scores no longer do: it waits for a full trace
                    // (`record_choices` sees them gone).
                    _ => self.ray_cache.forget(k),
                }
            }
        }
        (late.iter().zip(planned))
            .filter(|&(&(m, _, _), _)| chosen[m])
            .map(|(&(_, k, _), p)| (k, p))
            .collect()
    }

    /// Records the budget's choice (`chosen`, per candidate of `cands` in
    /// merged order): a chosen point leaves the waiting list, one not chosen
    /// waits (planned again next step, or, once demand has raised the
    /// bound past `max_wait` and it has waited [`REPLAN_WAITS`] steps,
    /// traced in full when its turn comes, or planned late,
    /// [`Self::plan_late`], with
    /// [`PipelineConfig::plan_late`](super::config::PipelineConfig::plan_late)).
    /// A point the loop memory verified (`Candidates::verified_at`) that
    /// waits starts its wait again, as one put to wait now. Returns the
    /// chosen planned points (indices into `batch`), the chosen points
    /// apart (keys), and how many waits started again.
    pub(super) fn record_choices(
        &mut self,
        batch: &Batch,
        plans: &[Plan],
        apart: &Apart,
        cands: &Candidates,
        chosen: &[bool],
        bound: u32,
    ) -> (Vec<usize>, Vec<u64>, u64) {
        let (at, merged) = (&cands.at, &cands.merged);
        let (mut chosen_at, mut chosen_apart) =
            (vec![false; at.len()], vec![false; apart.keys.len()]);
        for (&(a, j), &go) in merged.iter().zip(chosen) {
            if a {
                chosen_apart[j] = go;
            } else {
                chosen_at[j] = go;
            }
        }
        let mut take = Vec::new();
        let mut take_apart = Vec::new();
        // Those the loop memory verified, not chosen: their wait starts
        // again once they have been put back to wait.
        let mut restart = Vec::new();
        for (j, ((&k, how), &go)) in apart
            .keys
            .iter()
            .zip(&apart.how)
            .zip(&chosen_apart)
            .enumerate()
        {
            if go {
                self.waiting.done(k);
                take_apart.push(k);
                continue;
            }
            if cands.verified_apart[j] {
                restart.push(k);
            }
            match how {
                // One planned late waits so while its scores are kept.
                ApartAs::Late(_) => {
                    let full = self.ray_cache.get(k).is_none();
                    self.waiting.wait(k, full);
                }
                ApartAs::Full => self.waiting.wait(k, true),
                // As a planned point traced in full.
                ApartAs::Moving => {
                    self.ray_cache.forget(k);
                    self.waiting.wait(k, true);
                }
            }
        }
        for (j, (&b, &go)) in at.iter().zip(&chosen_at).enumerate() {
            let (i, k) = batch.owner[b];
            let key = key(i, k);
            if go {
                self.waiting.done(key);
                take.push(b);
                continue;
            }
            if cands.verified_at[j] {
                restart.push(key);
            }
            // Planned again next step, unless demand has raised the bound
            // and it has waited a while already. (By its age before the loop
            // memory, if it verified it, starts its wait again: one verified
            // young is planned again with its kept scores, at the planning's
            // cost each step. Taking a verified point off planning at once
            // instead left more points off a full trace at fixed budgets,
            // 9,906 against 8,499 in the memory's test at 240 rays a step
            // at c8ba72b, as it then costs a full trace when taken.)
            let waited = self.waiting.get(key).map_or(0, |w| w.0);
            let replan = bound <= self.config.max_wait || waited < REPLAN_WAITS;
            match &plans[b] {
                Plan::Rays { reached, .. } if replan || self.config.plan_late => {
                    self.ray_cache.mark_stale(key, reached);
                    self.waiting.wait(key, false);
                    if !replan {
                        // Its rays reached up to this step are stale.
                        self.waiting.plan_late(key, self.frame as u32);
                    }
                }
                _ => {
                    self.ray_cache.forget(key);
                    self.waiting.wait(key, true);
                }
            }
        }
        for &k in &restart {
            self.waiting.restart(k);
        }
        (take, take_apart, restart.len() as u64)
    }
}

/// `apart` (ascending keys) with the points of the step's `lists` of each
/// instance whose points wait apart as movers (`moving`) merged in, as
/// [`ApartAs::Moving`] (each once), those lists emptied.
fn with_movers(apart: Apart, lists: &mut [Vec<u32>], moving: impl Fn(usize) -> bool) -> Apart {
    let extra: usize = (0..lists.len())
        .filter(|&i| moving(i))
        .map(|i| lists[i].len())
        .sum();
    let mut out = Apart {
        keys: Vec::with_capacity(apart.keys.len() + extra),
        how: Vec::with_capacity(apart.keys.len() + extra),
    };
    let mut from = 0;
    for (i, l) in lists.iter_mut().enumerate() {
        // This instance's run of the ascending keys apart.
        let to = from + apart.keys[from..].partition_point(|&k| k >> 32 == i as u64);
        let run = from..to;
        from = to;
        if !moving(i) || l.is_empty() {
            out.keys.extend_from_slice(&apart.keys[run.clone()]);
            out.how.extend_from_slice(&apart.how[run]);
            continue;
        }
        l.sort_unstable();
        let reached = l.drain(..).map(|p| key(i, p));
        let mut waiting = apart.keys[run].iter().copied().peekable();
        let mut reached = reached.peekable();
        // Both ascending (every waiting point of a moving instance is
        // apart as a mover): merged, each once.
        loop {
            let next = match (waiting.peek(), reached.peek()) {
                (Some(&w), Some(&r)) if w <= r => {
                    if w == r {
                        reached.next();
                    }
                    waiting.next()
                }
                (_, Some(_)) => reached.next(),
                (Some(_), None) => waiting.next(),
                (None, None) => break,
            };
            if let Some(k) = next
                && out.keys.last() != Some(&k)
            {
                out.keys.push(k);
                out.how.push(ApartAs::Moving);
            }
        }
    }
    // Keys of no instance listed (none are made): kept as they were.
    out.keys.extend_from_slice(&apart.keys[from..]);
    out.how.extend_from_slice(&apart.how[from..]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_moving_instances_points_reached_join_its_waiting_ones_apart_each_once_in_key_order() {
        // Instance 0 rests (a static point waits for a full trace),
        // instance 1 moves (two of its points wait), instance 2 moves with
        // none waiting, instance 3 rests with points reached and its point
        // 0 waiting for a full trace, and a key of an instance past the
        // lists (5) waits planned late.
        let apart = Apart {
            keys: vec![key(0, 4), key(1, 2), key(1, 7), key(3, 0), key(5, 1)],
            how: vec![
                ApartAs::Full,
                ApartAs::Moving,
                ApartAs::Moving,
                ApartAs::Full,
                ApartAs::Late(3),
            ],
        };
        // Instance 1's list out of order, with a point twice.
        let mut lists = vec![vec![1, 9], vec![7, 1, 3, 1], vec![5, 0], vec![2]];
        let moving = |i: usize| i == 1 || i == 2;
        let out = with_movers(apart, &mut lists, moving);
        assert_eq!(
            out.keys,
            vec![
                key(0, 4),
                key(1, 1),
                key(1, 2),
                key(1, 3),
                key(1, 7),
                key(2, 0),
                key(2, 5),
                key(3, 0),
                key(5, 1)
            ]
        );
        assert_eq!(out.how[0], ApartAs::Full);
        assert!(out.how[1..7].iter().all(|h| *h == ApartAs::Moving));
        assert_eq!(out.how[7..], [ApartAs::Full, ApartAs::Late(3)]);
        // The movers' lists are emptied, the others' left to planning.
        assert_eq!(lists, vec![vec![1, 9], vec![], vec![], vec![2]]);
    }
}
