//! The ray budget of a step: which of the points that need tracing are
//! traced now, and which wait for a later step.
//!
//! Points are taken in order of priority until the budget is spent:
//! first every point that has waited its due (so none starves, and none
//! lags a full re-trace by more than the bound in force; its wait counts
//! from its last trace, or from the last step where the loop memory
//! verified that clients were not behind a full re-trace of it, `loops`,
//! [`PipelineConfig::loop_verify`]: a point's due is
//! that bound less a few steps (under half of it, at most [`MAX_SPREAD`]),
//! spread by a hash of the point, so that points that began to wait
//! together do not all come due in one step; see [`due`]), then by what a
//! ray spent on them is likely to
//! send, then the longest waiting, then in point order. A point that does
//! not fit is passed over for smaller ones.
//!
//! The likelihood is a point's *urgency* (`trend`): how near its AO
//! probably is to the send threshold from what clients hold, the distance
//! its last trace left plus the pace its AO moved at between its last two
//! traces times the steps it has waited plus one, as a share of the
//! threshold, at most [`MAX_URGENCY`]. The point of a rigid part that can
//! move, traced in full (reach says nothing of it), is at least as urgent as
//! the fastest pace near it makes it, the pace its cell's points moved at
//! in the last few steps (`trend::Heat`): a change sweeping over a part
//! (the rim of a box a bar slides out of) reaches a point's neighbours
//! first. (Not a deforming part's: its pose changes its points all at
//! once, and their own paces say how fast.) Where the scene's animations
//! loop, a point whose AO at the same moment of an earlier round would
//! not be sent against what clients hold has an urgency of 0, whatever
//! its trend (the loop memory, `loops`).
//! To it is added [`REACH_PRIOR`]
//! times the share of its rays motion reached, a prior for points whose
//! pace is not known yet. The sum, times the steps waited plus one (so
//! the budget goes round the points rather than to the same ones each
//! step), is divided by the rays the point costs. So with no trend every
//! reached ray counts alike: a mover's full trace and a static point's
//! few reached rays rank by age, not by kind. Every point's trend starts
//! from setup's trace. Where every candidate fits, the order changes
//! nothing. With
//! [`PipelineConfig::movers_every_step`] a moving instance's own points
//! count as having waited their longest: traced whatever the budget.
//!
//! The bound is [`PipelineConfig::max_wait`] while the budget affords the
//! points that reach it, and follows demand beyond that ([`next_bound`],
//! up to [`PipelineConfig::max_wait_limit`]): points that must wait
//! longer wait longer, instead of the step running past its period.
//! While the bound is above `max_wait`, a point that waited
//! [`REPLAN_WAITS`] steps is no longer planned ray by ray each step: it
//! forgets its kept scores and is traced in full when its turn comes (32
//! rays where a few may have been reached). With
//! [`PipelineConfig::plan_late`] it is planned *late* instead: once, when
//! the budget takes it, against the boxes of what moved in every step
//! since it was last planned (boxes that meet merged into one, so a ray
//! more may be cast, never one less). Until then it costs the rays known
//! stale, and while its instance rests it is kept out of each step's
//! planning, as a point waiting for a full trace is; where the rays it
//! then needs no longer fit the budget, it waits on (unless overdue).
//!
//! A point costs the rays it traces. With ray reuse that is only the
//! rays motion reached (the others' scores are kept, on the CPU tracer or
//! a backend that casts single rays, as psao-gpu's does with
//! `GpuBackend::with_single_rays(true)`),
//! and with early decisions a moving point that may stop early costs what
//! such points cast on average in the last step. (A point chosen in full
//! may then turn out to be open without a ray,
//! [`PipelineConfig::skip_open`]: it casts none, but was chosen at the
//! cost of its rays, so the choices do not depend on it; an automatic
//! budget measures the cost of a ray over the rays it paid for, the rays
//! such points would have cast included, so that the time they did not
//! take is spent on more rays, [`ns_per_priced_ray`].) A backend
//! that casts no single rays keeps no scores and traces every ray of a
//! point it traces, so the same budget takes fewer points there. With
//! the same costs the backends take the same decisions and send the same
//! frames, byte for byte, wherever their rays score alike (psao-gpu's
//! tests check it on the default scene and a morphing cube, with kept
//! scores and early decisions and without).
//!
//! [`PipelineConfig::max_wait`]: super::config::PipelineConfig::max_wait
//! [`PipelineConfig::max_wait_limit`]: super::config::PipelineConfig::max_wait_limit
//! [`PipelineConfig::movers_every_step`]: super::config::PipelineConfig::movers_every_step
//! [`PipelineConfig::skip_open`]: super::config::PipelineConfig::skip_open
//! [`PipelineConfig::plan_late`]: super::config::PipelineConfig::plan_late
//! [`PipelineConfig::loop_verify`]: super::config::PipelineConfig::loop_verify

use super::slots::PointSlots;

/// The weight of the share of a point's rays motion reached in its
/// priority, beside its urgency (see the module).
pub const REACH_PRIOR: f32 = 0.25;

/// The most urgency counts in a point's priority: past the threshold, a
/// point is as likely to be sent as it gets.
pub const MAX_URGENCY: f32 = 1.5;

/// How many rays one step may trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RayBudget {
    /// No limit: every point that motion reached is traced in its step
    /// (the baseline).
    Unlimited,
    /// At most this many rays per step (points that waited their due in
    /// force are traced beyond it).
    Rays(u64),
    /// The rays that `share` of the step's period affords at the cost of
    /// a ray measured over the last steps (from setup's trace at first;
    /// per ray paid for, the rays of points found open without casting
    /// one included, so that the time they did not take is spent too),
    /// less the time the step's other phases took.
    Auto {
        /// The share of the period, in (0, 1].
        share: f32,
    },
}

/// One point that needs tracing this step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Rays to trace.
    pub cost: u32,
    /// Share of its rays that motion reached (1 for a full trace).
    pub reached: f32,
    /// Steps it has waited.
    pub age: u32,
    /// The steps of waiting after which it is traced whatever the budget:
    /// at most the bound in force (see [`due`]).
    pub due: u32,
    /// How far its AO probably is from what clients hold now, as a share
    /// of the send threshold, from its trend (see the module; 0 where none
    /// is known).
    pub urgency: f32,
}

impl Candidate {
    /// Whether it has waited its due, or the `bound` in force: traced
    /// whatever the budget.
    pub fn overdue(&self, bound: u32) -> bool {
        self.age >= self.due.min(bound)
    }

    /// Its priority among those not overdue (see the module): what a ray
    /// spent on it is likely to send (its urgency, with the share motion
    /// reached as a prior), weighed by the steps waited so that the
    /// budget goes round instead of to the same points every step, per
    /// ray it costs.
    pub fn priority(&self) -> f32 {
        (self.reached.max(1e-3) * REACH_PRIOR + self.urgency.min(MAX_URGENCY))
            * (self.age as f32 + 1.0)
            / self.cost.max(1) as f32
    }
}

/// The most steps a point's due lies before the bound ([`due`]).
pub const MAX_SPREAD: u32 = 8;

/// The steps of waiting after which point `key` is traced whatever the
/// budget, under the bound `bound`: the bound less a number of steps
/// under half of it and under [`MAX_SPREAD`], from a hash of the key.
/// Points that began to wait in the same step (all those a moving part
/// left behind at once) then come due over that many steps, not all in
/// one step that would run far past the period; none waits longer than
/// the bound. Coming due earlier costs traces: with the bound at its
/// limit, where demand holds it, points come due about
/// `MAX_SPREAD / 2` steps early on average (4 of 60, 7% more forced
/// work), which is why the spread is capped.
pub fn due(key: u64, bound: u32) -> u32 {
    if bound <= 1 {
        return bound;
    }
    let spread = (bound / 2).min(MAX_SPREAD) as u128;
    let mut h = key.wrapping_add(0x9e37_79b9_7f4a_7c15);
    h = (h ^ (h >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    h ^= h >> 31;
    // The hash's place in [0, 1) scaled to the spread: a point keeps its
    // place among the others when the bound moves.
    bound - ((h as u128 * spread) >> 64) as u32
}

/// Which candidates are traced this step under `budget` rays (`None`: all
/// of them), those that waited `bound` steps whatever the budget, in the
/// order of the module's rules; `chosen[i]` for candidate `i`. Returns the
/// choices and the rays they cost.
pub fn select(cands: &[Candidate], budget: Option<u64>, bound: u32) -> (Vec<bool>, u64) {
    let Some(budget) = budget else {
        return (
            vec![true; cands.len()],
            cands.iter().map(|c| c.cost as u64).sum(),
        );
    };
    // Those that waited their due go first, whatever they cost.
    let mut chosen = vec![false; cands.len()];
    let mut spent = 0u64;
    let mut rest = Vec::with_capacity(cands.len());
    for (i, c) in cands.iter().enumerate() {
        if c.overdue(bound) {
            chosen[i] = true;
            spent += c.cost as u64;
        } else {
            rest.push(i);
        }
    }
    // By priority, computed once per candidate, then the longest waiting:
    // a total order (ties go by index).
    let weight: Vec<f32> = cands.iter().map(Candidate::priority).collect();
    let order = |&a: &usize, &b: &usize| {
        let (x, y) = (&cands[a], &cands[b]);
        weight[b]
            .total_cmp(&weight[a])
            .then(y.age.cmp(&x.age))
            .then(a.cmp(&b))
    };
    // In that order, each that fits what is left. Sorting them all would
    // cost more than the rest of the choice where tens of thousands wait
    // and a few hundred fit. So, a round at a time, only the first of
    // them in that order are taken out (`select_nth`) and sorted, each
    // taken if it fits: twice as many as fit at their mean cost (four
    // times in the next round, and so on), and never more than `left`
    // (past the points of no rays, each costs a ray or more). Of the
    // others only those that still fit (what is left only shrinks) go on
    // to the next round. The choice is the one a sort of all of them
    // gives, whatever the costs (a test checks it).
    if spent > budget {
        // Nothing else fits, not even a point of no rays.
        return (chosen, spent);
    }
    let mut left = budget - spent;
    // A point of no rays fits whatever is left (no plan gives one, but
    // the choice does not depend on it); one that costs more than is left
    // never fits (a part held whole costs `u32::MAX`).
    let mut pool: Vec<usize> = rest
        .into_iter()
        .filter(|&i| {
            chosen[i] |= cands[i].cost == 0;
            !chosen[i] && cands[i].cost as u64 <= left
        })
        .collect();
    // How many times as many as fit at the mean cost a round sorts:
    // doubled each round, so that skewed costs take few rounds.
    let mut times = 2usize;
    while !pool.is_empty() {
        let cost: u64 = pool.iter().map(|&i| cands[i].cost as u64).sum();
        let mean = (cost / pool.len() as u64).max(1);
        let fit = usize::try_from(left).unwrap_or(usize::MAX);
        let head = pool
            .len()
            .min(fit)
            .min(usize::try_from(left / mean).map_or(usize::MAX, |n| n.saturating_mul(times)))
            .max(1);
        times = times.saturating_mul(2);
        if head < pool.len() {
            pool.select_nth_unstable_by(head, order);
        }
        let first = &mut pool[..head];
        first.sort_unstable_by(order);
        for &i in first.iter() {
            let cost = cands[i].cost as u64;
            if cost <= left {
                chosen[i] = true;
                left -= cost;
                spent += cost;
            }
        }
        // The others that still fit, in place (no list a round).
        pool.drain(..head);
        pool.retain(|&i| cands[i].cost as u64 <= left);
    }
    (chosen, spent)
}

/// The bound on waiting for the step after one whose points that had
/// reached `bound` (overdue, traced whatever the budget) cost `forced`
/// rays under a budget of `budget`, and after which the longest wait is
/// `oldest`: more when the overdue points cost more than the budget
/// (demand beyond it: they take the step past its period), by the bound
/// times the share of the budget they overran it by (at least a step, at
/// most doubling); a step less when none was overdue and the longest wait
/// is under half the bound (the budget goes round the points well within
/// it); within
/// `[least, limit]`; a budget of 0 (an automatic budget whose step spent
/// its share before casting) raises it by a step. Under demand beyond the
/// budget the points that wait go round in about demand / budget steps:
/// the bound rises to about that, overshooting it by up to twice, and
/// comes down a step at a time once nothing is overdue.
pub fn next_bound(
    bound: u32,
    forced: u64,
    budget: u64,
    oldest: u32,
    least: u32,
    limit: u32,
) -> u32 {
    let next = if forced > budget && budget == 0 {
        // No budget left at all (an automatic budget whose step spent its
        // share before casting): nothing to measure the overrun by.
        bound.saturating_add(1)
    } else if forced > budget {
        // Up by the bound's share of the overdue cost beyond the budget
        // (at least a step, at most doubling): demand well beyond the
        // budget, as when motion starts, raises the bound in a few steps
        // instead of one step each.
        let over = (u128::from(bound) * u128::from(forced - budget))
            .div_ceil(u128::from(budget.max(1)))
            .clamp(1, u128::from(bound.max(1)));
        bound.saturating_add(over as u32)
    } else if forced == 0 && oldest.saturating_mul(2) < bound {
        bound.saturating_sub(1)
    } else {
        bound
    };
    next.clamp(least, limit.max(least))
}

/// Nanoseconds a ray the budget pays for costs, from a step's casting:
/// it took `elapsed` for `rays_cast` rays, and the points known open cast
/// none of the `uncast` rays they would have cast
/// ([`PipelineConfig::skip_open`]: chosen at what their rays cost, they
/// cast none). Divided by the rays cast alone, the cost would put the
/// open points' rays down as time the budget can spend again, and an
/// automatic budget would leave that share of its period unused (about
/// 9% on the default scene). `None` under 1,024 rays cast: too few to
/// time (a step whose points were nearly all open says little of what a
/// ray costs).
///
/// [`PipelineConfig::skip_open`]: super::config::PipelineConfig::skip_open
pub fn ns_per_priced_ray(elapsed: std::time::Duration, rays_cast: u64, uncast: u64) -> Option<f64> {
    let priced = rays_cast.saturating_add(uncast);
    (rays_cast >= 1024).then(|| elapsed.as_nanos() as f64 / priced as f64)
}

/// Steps a point with kept ray scores may wait and still be planned ray
/// by ray each step while demand has raised the bound on waiting: past
/// them it is traced in full when its turn comes, or planned late (see
/// the module). Planning tests each of its rays against the boxes of what
/// moved, every step it waits; with many points waiting that costs more
/// than the rays it saves.
pub const REPLAN_WAITS: u32 = 2;

/// The points waiting for a later step, by (instance, point) key: the
/// steps each has waited, whether it needs a full trace (it has no
/// kept scores; else its reached rays are marked stale in the cache), and
/// whether it is planned *late*: not each step it waits, but once, when
/// the budget takes it, against the boxes of what moved in every step
/// since it was last planned (see `Pipeline::plan_late`).
#[derive(Clone, Debug, Default)]
pub struct Waiting {
    /// Per point: 0 while it does not wait, else the steps it has waited
    /// times 4, plus 2 when it is planned late, plus 1 when it needs a
    /// full trace.
    state: PointSlots,
    /// Per point planned late, the step it was last planned in (the
    /// step's number, wrapping at 2^32).
    since: PointSlots,
    /// The keys of the points that wait, in no order, and of some that no
    /// longer do or twice (tidied by [`keys`](Self::keys)).
    list: Vec<u64>,
    /// Points waiting.
    count: usize,
}

/// A waiting point's state: its flag for a full trace.
const FULL: u32 = 1;
/// A waiting point's state: its flag for planning late.
const LATE: u32 = 2;
/// A waiting point's state: its age lies above the flags.
const AGE_SHIFT: u32 = 2;

impl Waiting {
    /// A waiting point's age and whether it needs a full trace.
    pub fn get(&self, key: u64) -> Option<(u32, bool)> {
        let s = self.state.get(key);
        (s != 0).then_some((s >> AGE_SHIFT, s & FULL != 0))
    }

    /// The step a waiting point planned late was last planned in.
    pub fn late_since(&self, key: u64) -> Option<u32> {
        (self.state.get(key) & LATE != 0).then(|| self.since.get(key))
    }

    /// Keeps `key` waiting one step more (`full`: it needs a full trace,
    /// which stays so once set, and is planned in no other way).
    pub fn wait(&mut self, key: u64, full: bool) {
        let s = self.state.get(key);
        if s == 0 {
            self.list.push(key);
            self.count += 1;
        }
        let age = ((s >> AGE_SHIFT) + 1).min(u32::MAX >> AGE_SHIFT);
        let flags = if s & FULL != 0 || full {
            FULL
        } else {
            s & LATE
        };
        self.state.set(key, (age << AGE_SHIFT) | flags);
    }

    /// Notes that waiting `key`, planned late, was planned in `step` (its
    /// rays reached up to it are to be marked stale).
    pub fn replanned(&mut self, key: u64, step: u32) {
        if self.state.get(key) & LATE != 0 {
            self.since.set(key, step);
        }
    }

    /// Plans waiting `key` (with kept scores, its rays reached up to
    /// `step` marked stale) late from now on; a point planned late
    /// already keeps the step it was last planned in.
    pub fn plan_late(&mut self, key: u64, step: u32) {
        let s = self.state.get(key);
        if s != 0 && s & (FULL | LATE) == 0 {
            self.state.set(key, s | LATE);
            self.since.set(key, step);
        }
    }

    /// Starts the wait of waiting point `key` again, as if put to wait in
    /// this step (its age 1; its flags kept): clients were found not
    /// behind a full re-trace of it (the loop memory verified it).
    pub fn restart(&mut self, key: u64) {
        let s = self.state.get(key);
        if s != 0 {
            self.state.set(key, (1 << AGE_SHIFT) | (s & (FULL | LATE)));
        }
    }

    /// Takes `key` off the list (it was traced).
    pub fn done(&mut self, key: u64) {
        if self.state.get(key) != 0 {
            self.state.set(key, 0);
            self.count -= 1;
        }
    }

    /// The waiting keys, ascending.
    pub fn keys(&mut self) -> Vec<u64> {
        let state = &self.state;
        self.list.retain(|&k| state.get(k) != 0);
        // Mostly ascending runs (each step adds its keys in order): the
        // stable sort merges them.
        self.list.sort();
        self.list.dedup();
        self.list.clone()
    }

    /// Points waiting.
    pub fn len(&self) -> usize {
        self.count
    }

    /// The longest wait, in steps.
    pub fn oldest(&self) -> u32 {
        self.list
            .iter()
            .map(|&k| self.state.get(k) >> AGE_SHIFT)
            .max()
            .unwrap_or(0)
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.state.memory_bytes() + self.since.memory_bytes() + self.list.capacity() as u64 * 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_is_priced_over_the_rays_paid_for_open_points_included() {
        use std::time::Duration;
        // 10,000 rays cast in 2 ms, and 3,200 rays that points known open
        // did not cast: 13,200 rays paid for.
        let ns = ns_per_priced_ray(Duration::from_millis(2), 10_000, 3_200).expect("timed");
        assert!((ns - 2e6 / 13_200.0).abs() < 1e-6, "{ns}");
        // Nothing open: per ray cast.
        let plain = ns_per_priced_ray(Duration::from_millis(2), 10_000, 0).expect("timed");
        assert!((plain - 200.0).abs() < 1e-9);
        // Too few rays cast to time, however many open points' rays.
        assert_eq!(
            ns_per_priced_ray(Duration::from_millis(1), 1_000, 40_000),
            None
        );
        assert!(ns_per_priced_ray(Duration::from_millis(1), 1_024, 0).is_some());
    }

    fn c(cost: u32, reached: f32, age: u32) -> Candidate {
        Candidate {
            cost,
            reached,
            age,
            due: u32::MAX,
            urgency: 0.0,
        }
    }

    #[test]
    fn the_wait_bound_follows_demand_within_its_limits() {
        // Overdue points cost a little more than the budget: a step more.
        assert_eq!(next_bound(8, 1000, 999, 8, 8, 60), 9);
        // A quarter more: a quarter more steps.
        assert_eq!(next_bound(16, 1250, 1000, 16, 8, 60), 20);
        // Far more: the bound doubles, within the limit.
        assert_eq!(next_bound(8, 5000, 1000, 8, 8, 60), 16);
        assert_eq!(next_bound(40, 5000, 1000, 40, 8, 60), 60);
        // No budget at all: a step, as there is no overrun to measure.
        assert_eq!(next_bound(8, 5000, 0, 8, 8, 60), 9);
        // At the limit it stays.
        assert_eq!(next_bound(60, 1000, 10, 60, 8, 60), 60);
        // Overdue points within the budget: unchanged.
        assert_eq!(next_bound(12, 1000, 1000, 12, 8, 60), 12);
        // None overdue but points near the bound: unchanged.
        assert_eq!(next_bound(12, 0, 1000, 6, 8, 60), 12);
        // None overdue and the longest wait under half: a step back,
        // never below the least.
        assert_eq!(next_bound(12, 0, 1000, 5, 8, 60), 11);
        assert_eq!(next_bound(8, 0, 1000, 0, 8, 60), 8);
        // A fixed bound (limit = least) never moves.
        assert_eq!(next_bound(8, 1 << 40, 0, 8, 8, 8), 8);
    }

    #[test]
    fn unlimited_takes_everything() {
        let (ch, spent) = select(&[c(32, 1.0, 0), c(4, 0.1, 0)], None, 8);
        assert_eq!(ch, vec![true, true]);
        assert_eq!(spent, 36);
    }

    fn u(cost: u32, reached: f32, age: u32, urgency: f32) -> Candidate {
        Candidate {
            urgency,
            ..c(cost, reached, age)
        }
    }

    #[test]
    fn with_no_trend_the_budget_goes_by_reach_per_ray_and_age() {
        let cands = [c(32, 1.0, 0), c(8, 0.25, 0), c(8, 0.25, 3), c(4, 0.5, 0)];
        // Per ray: the half-reached 4-ray point and the quarter-reached
        // one that waited 3 steps rank alike (the older first), then the
        // full trace and the other quarter-reached one alike (by index).
        // 44 rays: the first two, then the full trace.
        let (ch, spent) = select(&cands, Some(44), 8);
        assert_eq!(ch, vec![true, false, true, true]);
        assert_eq!(spent, 44);
        // Too little for the full trace: smaller ones still go.
        let (ch, _) = select(&cands, Some(20), 8);
        assert_eq!(ch, vec![false, true, true, true]);
    }

    #[test]
    fn the_budget_goes_where_a_ray_is_likeliest_to_send() {
        // A mover's full trace with no trend, a static point of 4 rays
        // near the threshold, and a full trace half-way there.
        let cands = [u(32, 1.0, 0, 0.0), u(4, 0.1, 0, 1.0), u(32, 1.0, 0, 0.5)];
        let (ch, spent) = select(&cands, Some(36), 8);
        assert_eq!(ch, vec![false, true, true]);
        assert_eq!(spent, 36);
        // Past the threshold counts as at most MAX_URGENCY: a far-gone
        // point of 32 rays does not outrank the 4-ray one.
        let cands = [u(32, 1.0, 0, 40.0), u(4, 0.1, 0, 1.0)];
        let (ch, _) = select(&cands, Some(32), 8);
        assert_eq!(ch, vec![false, true]);
    }

    #[test]
    fn the_budget_goes_round_the_points() {
        // Four alike points, a budget for two: each step the two that
        // waited go first, so no point waits two steps in a row.
        let mut ages = [0u32; 4];
        for _ in 0..6 {
            let cands: Vec<Candidate> = ages.iter().map(|&a| c(8, 1.0, a)).collect();
            let (ch, _) = select(&cands, Some(16), 8);
            assert_eq!(ch.iter().filter(|&&x| x).count(), 2);
            for (a, go) in ages.iter_mut().zip(ch) {
                *a = if go { 0 } else { *a + 1 };
            }
            assert!(ages.iter().all(|&a| a <= 1), "{ages:?}");
        }
        // A point half as reached, waiting twice as long, ranks with them.
        let (ch, _) = select(&[c(8, 1.0, 0), c(8, 0.5, 3)], Some(8), 8);
        assert_eq!(ch, vec![false, true]);
    }

    /// `select` as its rules say it, sorting every candidate.
    fn select_by_sorting_all(cands: &[Candidate], budget: u64, bound: u32) -> (Vec<bool>, u64) {
        let mut order: Vec<usize> = (0..cands.len()).collect();
        order.sort_by(|&a, &b| {
            let (x, y) = (&cands[a], &cands[b]);
            y.overdue(bound)
                .cmp(&x.overdue(bound))
                .then(y.priority().total_cmp(&x.priority()))
                .then(y.age.cmp(&x.age))
                .then(a.cmp(&b))
        });
        let (mut chosen, mut spent) = (vec![false; cands.len()], 0u64);
        for i in order {
            let c = &cands[i];
            if c.overdue(bound) || spent + c.cost as u64 <= budget {
                chosen[i] = true;
                spent += c.cost as u64;
            }
        }
        (chosen, spent)
    }

    #[test]
    fn choosing_sorts_only_what_can_fit_and_chooses_as_a_full_sort() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |m: u64| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) % m
        };
        for round in 0..600 {
            // Some rounds as where tens of thousands wait: many cheap
            // points (late ones cost their few stale rays) and a few full
            // traces, far more than fit, which takes the choice several
            // rounds of sorting.
            let many = round % 2 == 1;
            let n = if many { next(5000) } else { next(200) } as usize;
            let cands: Vec<Candidate> = (0..n)
                .map(|_| {
                    // 0 too, which no plan gives.
                    let cost = match (many, next(8)) {
                        (true, 0) => 32,
                        (true, _) => next(4) as u32,
                        (false, _) => next(40) as u32,
                    };
                    let urgency = next(5) as f32 / 2.0;
                    u(cost, next(9) as f32 / 8.0, next(12) as u32, urgency)
                })
                .collect();
            let budget = next(2000);
            let bound = 1 + next(12) as u32;
            assert_eq!(
                select(&cands, Some(budget), bound),
                select_by_sorting_all(&cands, budget, bound),
                "round {round}"
            );
        }
    }

    #[test]
    fn points_that_wait_together_come_due_over_a_few_steps() {
        assert_eq!(due(7, 0), 0);
        assert_eq!(due(7, 1), 1);
        for bound in [2u32, 3, 8, 60] {
            let range = (bound / 2).clamp(1, MAX_SPREAD);
            let mut count = vec![0u32; bound as usize + 1];
            for key in 0..10_000u64 {
                let d = due(key << 32 | (key * 7919 % 1000), bound);
                assert!(
                    d <= bound && d > bound - range,
                    "due {d} under bound {bound}"
                );
                count[d as usize] += 1;
            }
            // Every due in the range is taken, none by more than twice
            // its share.
            for d in bound + 1 - range..=bound {
                let n = count[d as usize];
                assert!(
                    n > 0 && n < 2 * 10_000 / range,
                    "{n} of 10000 due at {d} under {bound}"
                );
            }
        }
        // A candidate due before the bound goes whatever the budget.
        let early = Candidate {
            due: 5,
            ..c(32, 1.0, 5)
        };
        let (ch, spent) = select(&[early, c(8, 1.0, 0)], Some(0), 8);
        assert_eq!(ch, vec![true, false]);
        assert_eq!(spent, 32);
    }

    #[test]
    fn nothing_waits_past_max_wait() {
        let cands = [c(32, 1.0, 0), c(8, 0.25, 8)];
        let (ch, spent) = select(&cands, Some(0), 8);
        assert_eq!(ch, vec![false, true], "the old one goes over the budget");
        assert_eq!(spent, 8);
    }

    #[test]
    fn waiting_points_age_and_keep_needing_a_full_trace() {
        let mut w = Waiting::default();
        w.wait(5, true);
        w.wait(5, false);
        w.wait(2, false);
        assert_eq!(w.get(5), Some((2, true)));
        assert_eq!(w.keys(), vec![2, 5]);
        assert_eq!(w.oldest(), 2);
        w.done(5);
        assert_eq!(w.len(), 1);
        assert_eq!(w.get(5), None);
        assert_eq!(w.keys(), vec![2]);
        // Back on the list: one key, a fresh age.
        w.wait(5, false);
        w.done(5);
        w.wait(5, false);
        w.done(2);
        w.done(2);
        assert_eq!(w.keys(), vec![5]);
        assert_eq!((w.len(), w.get(5), w.oldest()), (1, Some((1, false)), 1));
        // Keys of other instances too.
        w.wait(super::super::ray_cache::key(3, 1), true);
        assert_eq!(w.keys(), vec![5, 3 << 32 | 1]);
    }

    #[test]
    fn a_point_planned_late_keeps_the_step_it_was_planned_in_until_replanned() {
        let mut w = Waiting::default();
        // Only a waiting point with kept scores is planned late.
        w.plan_late(7, 3);
        assert_eq!(w.late_since(7), None);
        w.wait(8, true);
        w.plan_late(8, 3);
        assert_eq!(w.late_since(8), None);
        w.wait(7, false);
        w.plan_late(7, 3);
        assert_eq!(w.late_since(7), Some(3));
        // Waiting on, it keeps its step and ages; asked again, the same.
        w.wait(7, false);
        w.plan_late(7, 4);
        assert_eq!((w.late_since(7), w.get(7)), (Some(3), Some((2, false))));
        // Planned in a later step (put back after the budget took it).
        w.replanned(7, 5);
        assert_eq!(w.late_since(7), Some(5));
        // Needing a full trace ends it; so does leaving the list.
        w.wait(7, true);
        assert_eq!((w.late_since(7), w.get(7)), (None, Some((3, true))));
        w.wait(9, false);
        w.plan_late(9, 6);
        w.done(9);
        w.wait(9, false);
        assert_eq!((w.late_since(9), w.get(9)), (None, Some((1, false))));
        assert_eq!(w.oldest(), 3);
    }
}
