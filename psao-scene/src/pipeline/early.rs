//! Early decisions (issue 20): a moving instance's point casts its rays
//! in a well-spread order and stops as soon as it is known, with a stated
//! confidence, that its AO stays within the send threshold of what
//! clients hold, so that nothing would be sent.
//!
//! **The test.** A point keeps each ray's score from its last cast (its
//! rays are the same set every time: the order only says which are cast
//! first), and which rays changed then. The full trace's AO now is
//! `F = C + (sum of the changes) / n`, `C` the mean of the kept scores and
//! `n` the rays: a control variate, so only the *change* is estimated,
//! which is small and mostly zero where motion changes little.
//! - The rays that changed at their last cast are cast first, all of them
//!   (when they are at most half): their change is summed exactly.
//! - The others are cast in the spread order (sorted by bit-reversed
//!   index, so any run of them covers the bands from the normal to the
//!   horizon), starting a quarter further every step of the pipeline.
//!   After a quarter, a half and three quarters of them (each at least 4
//!   rays), the mean change `m` of those cast so far
//!   estimates the rest's, with standard error
//!   `sqrt(max(s², floor²) / k * (r - k) / (r - 1))` for `k` of `r` rays cast
//!   (`s²` their sample variance; the last factor because they are drawn
//!   from the point's own rays without replacement), scaled by `r / n`.
//! - The point stops when `|F̂ - h| + z · se <= t`, `h` the AO clients hold
//!   and `t` the send threshold (`ao_steps / 255`): had the estimate erred
//!   by less than `z` standard errors, the full trace would quantize
//!   within the threshold of `h` and not be sent. Where clients hold less
//!   than open, it must also be that `F̂ + z · se` stays below what
//!   quantizes to open (254.5 / 255), since a trace that comes out open is
//!   sent whatever the threshold (`psao_codec::SentPoint::changed`). A
//!   point that does not stop casts every ray, and its AO is the full
//!   trace's, bit for bit.
//!
//! The rays sampled are a fixed spread, not a random draw, so `z` is a
//! normal approximation's confidence, not a proven one: the audit below
//! measures how often it is wrong.
//!
//! `floor` is [`EarlyDecisions::sd_floor`] for a point whose normal held
//! still since its last cast (a sliding box: its rays are the same rays),
//! and [`EarlyDecisions::sd_floor_turning`] for one whose normal turned (a
//! turning or deforming instance's: its rays turn with it, and a ray that
//! sweeps onto a limb changes all at once, which a few rays that did not
//! change cannot rule out).
//!
//! **What it can add.** A wrong decision leaves clients holding `h` where
//! a full trace would have sent a value more than the threshold away (or
//! an open one, where `h` is short of open); by
//! how much is what the estimate missed beyond `z` standard errors. A
//! point traced four steps in a row casts every ray among the first in one
//! of them (the rotation); a point that stopped early
//! [`max_stops`](EarlyDecisions::max_stops) times in a row traces in full,
//! so no wrong decision outlives that many of its traces; and a point that
//! stopped early in the last step of its instance's motion is traced again
//! in full once the instance is still (in the next step, or under a ray
//! budget when its turn comes).
//! [`Pipeline::early_audit`](super::Pipeline::early_audit) re-traces the
//! last step's early stops in full and counts the wrong ones; BENCHMARKS.md
//! measures them and their cost in PSNR.
//!
//! The CPU tracer decides early, and so does a backend that casts single
//! rays (psao-gpu's with `GpuBackend::with_single_rays(true)`), on its own
//! scores by the same [`EarlyRun`]; only
//! for points of instances that moved or deformed this step (a static
//! point re-traces only the rays motion reached, the others' scores
//! kept: see `reach`).

use psao_codec::wire::point::quantize_ao;
use rustc_hash::FxHashMap;

use super::reach::RayMask;
use super::slots::PointSlots;

/// Early decisions' settings ([`PipelineConfig::early`]).
///
/// [`PipelineConfig::early`]: super::config::PipelineConfig::early
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EarlyDecisions {
    /// How many standard errors of the estimate must fit between it and
    /// the send threshold for a point to stop (3).
    pub z: f32,
    /// The least standard deviation of a ray's score change the test
    /// assumes (0.02), so that a few rays that all changed alike (often:
    /// not at all) do not pass for certainty.
    pub sd_floor: f32,
    /// The least standard deviation assumed for a point whose normal
    /// turned since its scores were kept (a turning or deforming
    /// instance's: its rays turn with it, and a ray that swept onto a
    /// limb changes all at once), 0.1.
    pub sd_floor_turning: f32,
    /// After this many early stops in a row a point traces all its rays
    /// (8).
    pub max_stops: u8,
}

impl Default for EarlyDecisions {
    fn default() -> Self {
        EarlyDecisions {
            z: 3.0,
            sd_floor: 0.02,
            sd_floor_turning: 0.1,
            max_stops: 8,
        }
    }
}

/// What [`Pipeline::early_audit`](super::Pipeline::early_audit) found:
/// the last step's early stops against full traces.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EarlyAudit {
    /// Points that stopped early in the last step, each traced again in
    /// full.
    pub checked: u64,
    /// Those whose full trace would have been sent (the wrong decisions).
    pub wrong: u64,
    /// The largest gap, in 1/255 steps, between a full trace and what
    /// clients hold, over the points checked (at most the send threshold
    /// where every decision was right).
    pub worst_steps: u8,
}

/// A moving point's kept scores.
#[derive(Clone, Debug)]
pub(super) struct Kept {
    /// Each ray's score as last cast.
    pub scores: Box<[f32]>,
    /// The point's world normal then: its rays turn with it.
    pub normal: glam::Vec3,
    /// The rays whose score changed when last cast, by more than
    /// [`CHANGED`] (all of them after a full trace with nothing kept
    /// before it).
    pub changed: RayMask,
    /// Early stops in a row.
    pub stops: u8,
}

/// The kept scores of moving instances' points, by (instance, point), up
/// to a number of points. An instance's entries go when it stops moving
/// ([`KeptScores::keep_moving`]).
#[derive(Debug, Default)]
pub(super) struct KeptScores {
    max_entries: usize,
    /// Bytes one entry takes, with the map's share.
    entry_bytes: u64,
    entries: FxHashMap<u64, Kept>,
    /// The instances that hold entries.
    instances: std::collections::BTreeSet<usize>,
    /// Per point, its entry's stops in a row plus 1 (0 where it holds
    /// none): what [`KeptScores::may_stop`] reads for each of a step's
    /// tens of thousands of candidates, along memory in point order,
    /// where a look-up in `entries` would miss the cache (about 2 ms a
    /// step on a morphing cube of 61,000 points).
    stops: PointSlots,
}

impl KeptScores {
    /// A store of points with `rays` rays, holding at most `max_bytes` of
    /// scores, plus each point's stops in a row: four bytes a point (up
    /// to eight, as arrays grow) of the instances that have held entries
    /// since they last rested.
    pub fn new(rays: u32, max_bytes: u64) -> KeptScores {
        let entry_bytes = rays as u64 * 4
            + (rays as u64).div_ceil(64) * 8
            + std::mem::size_of::<(u64, Kept)>() as u64
            + 8;
        KeptScores {
            max_entries: (max_bytes / entry_bytes) as usize,
            entry_bytes,
            entries: FxHashMap::default(),
            instances: Default::default(),
            stops: PointSlots::default(),
        }
    }

    /// Takes a point's entry out (put it back with [`Self::put`]).
    pub fn take(&mut self, key: u64) -> Option<Kept> {
        let kept = self.entries.remove(&key)?;
        self.stops.set(key, 0);
        Some(kept)
    }

    /// Whether a point holds scores it may stop early over (fewer than
    /// `max_stops` stops in a row).
    pub fn may_stop(&self, key: u64, max_stops: u8) -> bool {
        let s = self.stops.get(key);
        s != 0 && s - 1 < u32::from(max_stops)
    }

    /// Puts a point's entry (back); a new one only while there is room.
    pub fn put(&mut self, key: u64, kept: Kept) {
        if self.entries.len() < self.max_entries || self.entries.contains_key(&key) {
            self.stops.set(key, u32::from(kept.stops) + 1);
            self.entries.insert(key, kept);
            self.instances.insert((key >> 32) as usize);
        }
    }

    /// Drops the entries of the instances that did not move or deform in
    /// this step (`changed[i]` false): their points are traced in full
    /// when they move again, and their room goes to the movers.
    pub fn keep_moving(&mut self, changed: &[bool]) {
        let rested: Vec<usize> = self
            .instances
            .iter()
            .copied()
            .filter(|&i| !changed.get(i).copied().unwrap_or(false))
            .collect();
        if rested.is_empty() {
            return;
        }
        for &i in &rested {
            self.instances.remove(&i);
            self.stops.drop_instance(i);
        }
        self.entries
            .retain(|&k, _| !rested.contains(&((k >> 32) as usize)));
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.entries.capacity() as u64 * self.entry_bytes + self.stops.memory_bytes()
    }
}

/// The rays whose score moved by more than [`CHANGED`] from `before` to
/// `now`.
pub(super) fn changed_rays(before: &[f32], now: &[f32]) -> RayMask {
    let mut m = RayMask::none(now.len() as u32);
    for (k, (&a, &b)) in before.iter().zip(now).enumerate() {
        if ((b - a) as f64).abs() > CHANGED {
            m.set(k as u32);
        }
    }
    m
}

/// The order a point's `n` rays are cast in: sorted by their bit-reversed
/// index, so every prefix is spread over the rays' strata (ray `k` lies
/// in the `k`-th of `n` bands from the normal to the horizon).
pub(super) fn ray_order(n: u32) -> Vec<u32> {
    let mut order: Vec<u32> = (0..n).collect();
    order.sort_by_key(|k| k.reverse_bits());
    order
}

/// Where in [`ray_order`] step `frame` starts: a quarter further each
/// step, so that within four steps every ray is cast first once.
pub(super) fn rotation(n: u32, frame: u64) -> usize {
    if n == 0 {
        return 0;
    }
    ((frame % 4) * n.div_ceil(4) as u64 % n as u64) as usize
}

/// A ray's score change above which it counts as changed (its hit moved
/// by more than a thousandth of the radius): below it, rounding in the
/// hit distance of a surface sliding along itself (a box sliding on a
/// floor sees the floor at the same distance, up to the last bits).
const CHANGED: f64 = 1e-3;

/// The least AO that quantizes to fully open (255).
const OPEN_FROM: f64 = 254.5 / 255.0;

/// What an [`EarlyRun`] came to ([`EarlyRun::finish`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Outcome {
    /// The AO of the full trace, `None` when the point stopped early
    /// (nothing to send).
    pub value: Option<f32>,
    /// Rays cast.
    pub cast: u32,
}

/// Casts a point's rays over its `kept` scores (updated in place, with
/// the rays whose score changed), with `score(k)` giving ray `k`'s score
/// now, and stops early when the test of the module says that the full
/// trace's AO lies within `tolerance` of `held`: an [`EarlyRun`] whose
/// runs are cast as they come (the tests' way in).
#[cfg(test)]
pub(super) fn trace_early(
    order: &[u32],
    rot: usize,
    kept: &mut Kept,
    held: f32,
    tolerance: f32,
    test: &EarlyDecisions,
    mut score: impl FnMut(u32) -> f32,
) -> Outcome {
    let mut run = EarlyRun::new(order, rot, kept, held, tolerance, test);
    while !run.wants().is_empty() {
        run.take_each(kept, &mut score);
    }
    run.finish(kept)
}

/// One point's early decision, a run of rays at a time, so that a caller
/// may cast each run where it likes (the CPU tracer at once, a backend
/// for many points together) with the same outcome, bit for bit.
///
/// The rays that changed at their last cast go first, all of them; then
/// the others in `order` from `rot` on, tested after a quarter, a half
/// and three quarters of them (each at least 4 rays, fewer than all).
/// When more than half the rays changed (a turning or deforming point,
/// whose rays all turn with it) they are all sampled alike in `order`. A
/// point that does not stop casts every ray; its value is then
/// [`ao_of_scores`](crate::trace::ao::ao_of_scores) of the new scores,
/// what a full trace gives, bit for bit. Which rays each run holds
/// depends on the kept scores' marks alone, never on the scores cast.
#[derive(Clone, Debug)]
pub(super) struct EarlyRun {
    /// The rays in the order they are cast: those enumerated (that
    /// changed last time), then the sampled ones.
    rays: Vec<u32>,
    /// How many of `rays` are enumerated.
    enumerated: usize,
    /// Where each run ends in `rays` (the last at `rays.len()`, the
    /// others at a check): the first `runs` of them.
    ends: [usize; 4],
    /// How many runs there are.
    runs: usize,
    /// The run to cast next (`runs`: done).
    next: usize,
    /// How many of `rays` were cast.
    at: usize,
    /// The mean of the kept scores.
    c: f64,
    /// The enumerated rays' summed change.
    exact: f64,
    /// The sampled rays' summed change and summed squared change.
    sum: f64,
    sum2: f64,
    /// The rays whose score changed, of those cast.
    changed: RayMask,
    held: f32,
    tolerance: f32,
    test: EarlyDecisions,
    stopped: bool,
}

impl EarlyRun {
    /// The run of a point with `kept` scores, against `held` (what
    /// clients hold) within `tolerance`.
    pub fn new(
        order: &[u32],
        rot: usize,
        kept: &Kept,
        held: f32,
        tolerance: f32,
        test: &EarlyDecisions,
    ) -> EarlyRun {
        let n = kept.scores.len();
        let rays = n as u32;
        let c = kept.scores.iter().map(|&s| s as f64).sum::<f64>() / n.max(1) as f64;
        let active = kept.changed.count() as usize;
        let enumerate = active * 2 <= n;
        let mut list: Vec<u32> = Vec::with_capacity(n);
        if enumerate {
            list.extend((0..rays).filter(|&k| kept.changed.has(k)));
        }
        let enumerated = list.len();
        list.extend(
            (0..n)
                .map(|j| order[(j + rot) % n])
                .filter(|&k| !(enumerate && kept.changed.has(k))),
        );
        let rest = n - enumerated;
        let (mut ends, mut runs) = ([n; 4], 0);
        for m in [rest / 4, rest / 2, 3 * rest / 4] {
            if m >= 4 && m < rest && (runs == 0 || ends[runs - 1] != enumerated + m) {
                ends[runs] = enumerated + m;
                runs += 1;
            }
        }
        // The last run, to the end.
        runs += 1;
        EarlyRun {
            rays: list,
            enumerated,
            ends,
            runs,
            next: 0,
            at: 0,
            c,
            exact: 0.0,
            sum: 0.0,
            sum2: 0.0,
            changed: RayMask::none(rays),
            held,
            tolerance,
            test: *test,
            stopped: false,
        }
    }

    /// The rays to cast next, in order (none once decided).
    pub fn wants(&self) -> &[u32] {
        match self.ends[..self.runs].get(self.next) {
            Some(&end) if !self.stopped => &self.rays[self.at..end],
            _ => &[],
        }
    }

    /// Takes the scores of the rays [`wants`](Self::wants) gave into
    /// `kept`, `score(k)` giving ray `k`'s (called for each in that
    /// order), and tests whether the point may stop.
    pub fn take_each(&mut self, kept: &mut Kept, mut score: impl FnMut(u32) -> f32) {
        let Some(&end) = self.ends[..self.runs]
            .get(self.next)
            .filter(|_| !self.stopped)
        else {
            return;
        };
        for j in self.at..end {
            let k = self.rays[j];
            let s = score(k);
            let d = (s - kept.scores[k as usize]) as f64;
            kept.scores[k as usize] = s;
            if d.abs() > CHANGED {
                self.changed.set(k);
            }
            if j < self.enumerated {
                self.exact += d;
            } else {
                self.sum += d;
                self.sum2 += d * d;
            }
        }
        self.at = end;
        self.next += 1;
        if self.next < self.runs {
            self.stopped = self.may_stop();
        }
    }

    /// The module's test after the rays cast so far.
    fn may_stop(&self) -> bool {
        let n = self.rays.len();
        let rest = n - self.enumerated;
        let m = self.at - self.enumerated;
        let mean = self.sum / m as f64;
        let var = ((self.sum2 - m as f64 * mean * mean) / (m - 1) as f64)
            .max((self.test.sd_floor as f64).powi(2));
        // The rest's share of the rays times the error of its mean.
        let se = rest as f64 / n as f64
            * (var / m as f64 * (rest - m) as f64 / (rest - 1) as f64).sqrt();
        let estimate = self.c + (self.exact + mean * rest as f64) / n as f64;
        let margin = self.test.z as f64 * se;
        // A full trace that could be open is sent whatever the threshold
        // (`SentPoint::changed`), unless clients hold open.
        let held_below_open = quantize_ao(self.held) != u8::MAX;
        let could_open = held_below_open && estimate + margin >= OPEN_FROM;
        !could_open && (estimate - self.held as f64).abs() + margin <= self.tolerance as f64
    }

    /// Ends the run: `kept`'s marks become the rays that changed (a ray
    /// not cast, of a point that stopped, keeps its mark).
    pub fn finish(self, kept: &mut Kept) -> Outcome {
        let mut changed = self.changed;
        for &k in &self.rays[self.at..] {
            if kept.changed.has(k) {
                changed.set(k);
            }
        }
        kept.changed = changed;
        Outcome {
            value: (!self.stopped).then(|| crate::trace::ao::ao_of_scores(&kept.scores)),
            cast: self.at as u32,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::ao::ao_of_scores;

    #[test]
    fn the_order_is_a_spread_permutation_and_rotates() {
        let o = ray_order(32);
        let mut sorted = o.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..32).collect::<Vec<_>>());
        // The first quarter takes one ray from every four bands.
        let mut first: Vec<u32> = o[..8].to_vec();
        first.sort_unstable();
        assert_eq!(first, vec![0, 4, 8, 12, 16, 20, 24, 28]);
        let odd = ray_order(24);
        let mut s = odd.clone();
        s.sort_unstable();
        assert_eq!(s, (0..24).collect::<Vec<_>>());
        assert_eq!(
            (0..4).map(|f| rotation(32, f)).collect::<Vec<_>>(),
            vec![0, 8, 16, 24]
        );
        assert_eq!(rotation(32, 4), 0);
        assert_eq!(rotation(0, 3), 0);
    }

    /// A kept entry of `scores`, none marked as changed.
    fn stable(scores: &[f32]) -> Kept {
        Kept {
            scores: scores.into(),
            normal: glam::Vec3::Z,
            changed: RayMask::none(scores.len() as u32),
            stops: 0,
        }
    }

    #[test]
    fn an_unchanged_point_stops_after_a_quarter_and_a_changed_one_traces_all() {
        let order = ray_order(32);
        let test = EarlyDecisions::default();
        let before: Vec<f32> = (0..32).map(|k| (k as f32 * 0.37).fract()).collect();
        let held = ao_of_scores(&before);
        let mut kept = stable(&before);
        let out = trace_early(&order, 0, &mut kept, held, 8.0 / 255.0, &test, |k| {
            before[k as usize]
        });
        assert_eq!(
            out,
            Outcome {
                value: None,
                cast: 8
            }
        );
        // Every ray darker by 0.2: far past the threshold, traced in full,
        // with the full trace's value bit for bit, every ray marked.
        let now: Vec<f32> = before.iter().map(|s| (s - 0.2).max(0.0)).collect();
        let mut kept = stable(&before);
        let mut cast = 0;
        let out = trace_early(&order, 8, &mut kept, held, 8.0 / 255.0, &test, |k| {
            cast += 1;
            now[k as usize]
        });
        assert_eq!(out.value, Some(ao_of_scores(&now)));
        assert_eq!((out.cast, cast), (32, 32));
        assert_eq!(kept.scores[..], now[..]);
        let differ = before.iter().zip(&now).filter(|(b, n)| b != n).count();
        assert_eq!(kept.changed.count() as usize, differ);
    }

    #[test]
    fn a_point_that_may_come_out_open_does_not_stop_unless_clients_hold_open() {
        let order = ray_order(32);
        let test = EarlyDecisions::default();
        // Every ray scoring `score`, last time and now, clients holding
        // `held`: the outcome and the rays cast.
        let early = |score: f32, held: f32| {
            let scores = vec![score; 32];
            let mut kept = stable(&scores);
            let out = trace_early(&order, 0, &mut kept, held, 8.0 / 255.0, &test, |k| {
                scores[k as usize]
            });
            (out.value, out.cast)
        };
        // Open (255), clients 5 steps less: within the threshold, but a
        // trace that comes out open is sent, so every ray is cast.
        assert_eq!(early(1.0, 250.0 / 255.0), (Some(1.0), 32));
        // Clients hold open: nothing to send, it stops after a quarter.
        assert_eq!(early(1.0, 1.0), (None, 8));
        // Far from open (a dark point, held as it is): it stops.
        assert_eq!(early(0.5, 0.5), (None, 8));
    }

    #[test]
    fn rays_that_changed_last_time_are_all_cast_first() {
        // Four rays changed at their last cast and change again: they are
        // summed exactly, so the point stops on the rest's sample only when
        // their change is within the threshold.
        let order = ray_order(32);
        let test = EarlyDecisions::default();
        let before = vec![1.0f32; 32];
        let mut kept = stable(&before);
        for k in 12..16 {
            kept.changed.set(k);
        }
        let mut now = before.clone();
        for s in &mut now[12..16] {
            *s = 0.0;
        }
        let mut cast = Vec::new();
        let out = trace_early(&order, 0, &mut kept, 1.0, 8.0 / 255.0, &test, |k| {
            cast.push(k);
            now[k as usize]
        });
        assert_eq!(&cast[..4], &[12, 13, 14, 15]);
        assert_eq!(out.value, Some(ao_of_scores(&now)), "4/32 darker: sent");
        // A small change on them: stops after them and a quarter of the
        // rest; the marks stay on the rays that changed.
        let mut kept = stable(&before);
        for k in 12..16 {
            kept.changed.set(k);
        }
        now[12..16].copy_from_slice(&[0.99; 4]);
        let out = trace_early(&order, 0, &mut kept, 1.0, 8.0 / 255.0, &test, |k| {
            now[k as usize]
        });
        assert_eq!(
            out,
            Outcome {
                value: None,
                cast: 4 + 7
            }
        );
        assert_eq!(kept.changed.count(), 4);
    }

    #[test]
    fn a_change_in_rays_not_yet_cast_is_caught_by_the_spread() {
        // Four neighbouring bands (one in eight of the rays) go dark while
        // nothing was marked: the first quarter of the spread order meets
        // one of them, and the change's variance keeps the point from
        // stopping.
        let order = ray_order(32);
        let test = EarlyDecisions::default();
        let before = vec![1.0f32; 32];
        let mut now = before.clone();
        for s in &mut now[12..16] {
            *s = 0.0;
        }
        for rot in 0..4 {
            let mut kept = stable(&before);
            let out = trace_early(
                &order,
                rotation(32, rot),
                &mut kept,
                1.0,
                8.0 / 255.0,
                &test,
                |k| now[k as usize],
            );
            assert_eq!(out.value, Some(ao_of_scores(&now)), "rotation {rot}");
            assert_eq!(kept.changed.count(), 4);
        }
    }

    #[test]
    fn the_stated_confidence_holds_on_random_changes() {
        // Points whose rays change at random by small amounts around a
        // shift: count the stops whose full trace would have been sent.
        let order = ray_order(32);
        let test = EarlyDecisions::default();
        let tol = 8.0 / 255.0;
        let (mut stops, mut wrong) = (0, 0);
        for p in 0..4000u32 {
            let before: Vec<f32> = (0..32).map(|k| crate::random::uniform(1, p, k)).collect();
            let shift = (crate::random::uniform(2, p, 0) - 0.5) * 0.1;
            let now: Vec<f32> = (0..32)
                .map(|k| {
                    let noise = (crate::random::uniform(3, p, k) - 0.5) * 0.1;
                    (before[k as usize] + shift + noise).clamp(0.0, 1.0)
                })
                .collect();
            let held = ao_of_scores(&before);
            let mut kept = stable(&before);
            let out = trace_early(
                &order,
                rotation(32, p as u64),
                &mut kept,
                held,
                tol,
                &test,
                |k| now[k as usize],
            );
            if out.value.is_none() {
                stops += 1;
                if (ao_of_scores(&now) - held).abs() > tol {
                    wrong += 1;
                }
            }
        }
        assert!(stops > 400, "the test stops where it can: {stops}");
        // z = 3: 0.27% of the decisions on a normal estimate (this run:
        // 5 of 1,904); at most twice that.
        assert!(wrong * 1000 <= stops * 6, "{wrong} wrong of {stops} stops");
    }

    #[test]
    fn an_instance_that_rests_gives_its_scores_up() {
        let mut kept = KeptScores::new(4, 1 << 20);
        let entry = |stops| Kept {
            scores: vec![1.0; 4].into(),
            normal: glam::Vec3::Z,
            changed: changed_rays(&[1.0, 0.5, 1.0, 1.0], &[1.0, 0.6, 1.0, 1.0005]),
            stops,
        };
        assert_eq!(
            entry(0).changed.count(),
            1,
            "a change within CHANGED is none"
        );
        kept.put(crate::pipeline::ray_cache::key(0, 3), entry(0));
        kept.put(crate::pipeline::ray_cache::key(1, 3), entry(8));
        assert!(kept.may_stop(crate::pipeline::ray_cache::key(0, 3), 8));
        assert!(
            !kept.may_stop(crate::pipeline::ray_cache::key(1, 3), 8),
            "stopped its most"
        );
        assert!(
            !kept.may_stop(crate::pipeline::ray_cache::key(0, 4), 8),
            "nothing kept"
        );
        // Instance 1 still moves, 0 rests.
        kept.keep_moving(&[false, true]);
        assert!(kept.take(crate::pipeline::ray_cache::key(0, 3)).is_none());
        assert!(kept.take(crate::pipeline::ray_cache::key(1, 3)).is_some());
        // A store too small for one entry keeps none.
        let mut none = KeptScores::new(32, 16);
        none.put(0, entry(0));
        assert!(none.take(0).is_none());
    }

    #[test]
    fn may_stop_reads_what_the_entries_hold_through_takes_puts_and_rests() {
        use crate::pipeline::ray_cache::key;
        use std::collections::HashMap;
        let entry = |stops| Kept {
            scores: vec![1.0; 4].into(),
            normal: glam::Vec3::Z,
            changed: RayMask::none(4),
            stops,
        };
        // Room for 40 entries (a full store turns new ones away).
        let mut kept = KeptScores::new(4, 40 * KeptScores::new(4, 0).entry_bytes);
        let mut model: HashMap<u64, u8> = HashMap::new();
        let mut x = 0x9e37_79b9_u64;
        for _ in 0..4000 {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            let (i, k) = ((x >> 60) as usize % 3, (x >> 33) as u32 % 64);
            let stops = [0, 1, 7, 8, 9, 254, 255][(x >> 20) as usize % 7];
            match (x >> 12) % 8 {
                0..=3 => {
                    if model.len() < 40 || model.contains_key(&key(i, k)) {
                        model.insert(key(i, k), stops);
                    }
                    kept.put(key(i, k), entry(stops));
                }
                4..=6 => {
                    let taken = kept.take(key(i, k)).map(|e| e.stops);
                    assert_eq!(taken, model.remove(&key(i, k)));
                }
                _ => {
                    let changed = [(x >> 8) & 1 == 1, (x >> 9) & 1 == 1, false];
                    kept.keep_moving(&changed);
                    model.retain(|&key, _| changed[(key >> 32) as usize]);
                }
            }
            for i in 0..4 {
                for k in 0..70 {
                    for max in [0, 8, 255] {
                        let held = model.get(&key(i, k));
                        assert_eq!(
                            kept.may_stop(key(i, k), max),
                            held.is_some_and(|&s| s < max),
                            "point ({i}, {k}), max_stops {max}, held {held:?}"
                        );
                    }
                }
            }
        }
    }
}
