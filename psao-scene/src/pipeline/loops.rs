//! The loop memory (issue 20): where a scene's animation loops, a
//! point's AO at a moment of the loop is what it was at that moment of an
//! earlier round, so what it was then predicts what it is now.
//!
//! Every animation of a scene loops over its own duration
//! ([`Scene::loop_period`](crate::Scene::loop_period) finds the shortest
//! time after which all of them start again together). The memory keeps,
//! per point traced under a ray budget, its quantized AO at each slot of
//! the loop it was traced in (a slot is one step of the loop at 60 Hz, or
//! a [`MAX_SLOTS`]-th of a loop longer than 20 s), with the round and the
//! time within the slot it was traced at. It serves two rules:
//!
//! - **Ranking.** When the budget ranks a point whose AO at the same slot
//!   of an earlier round would not be sent against what clients hold, it
//!   ranks as one with nothing to send (urgency 0: only the share of its
//!   rays motion reached and its wait rank it, as for a point without a
//!   trend), below the points that changed. A point the memory knows
//!   nothing of, or whose remembered AO would be sent, ranks by its trend
//!   as before. A wrong prediction (where a loop's end jumps, or the pose
//!   a slot stands for drifts between rounds) costs ranking only.
//! - **Verifying.** Where the scene's pose is a function of the time
//!   within the loop ([`jumps`] is `Some`: every animation's duration
//!   divides the period exactly, so that the same time within the loop
//!   poses every part alike), a point's remembered AO traced at a time
//!   within the loop at most [`VERIFY_TOLERANCE`] from now, with no jump
//!   of the pose between (an animation's restart where its end does not
//!   pose as its start, a key of a step interpolation), is a full trace
//!   of the scene as it is posed now, to within that much of animation
//!   time. Where it would not be sent against what clients
//!   hold, clients are not behind a full re-trace: the point's wait
//!   starts again, as if traced (it keeps waiting for the rays motion
//!   reached, ranked as one with nothing to send). So the bound on
//!   waiting is kept, counted from the last trace or verification,
//!   without tracing the points a looping part keeps reaching but
//!   leaves as they were (the wheel wells of a truck whose wheels turn).
//!   Only the remembered AO's round is not needed here: any round, this
//!   one included, poses the same at the same time within the loop.
//!   Nothing is sent from the memory: a point that would be sent is
//!   traced.
//!
//! Predicting only *nothing to send*, and leaving the points that would
//! be sent to their trends, is measured to be the safer rule:
//! promoting those too (urgency from the remembered AO) traced fewer,
//! dearer points under demand beyond the budget and left more points off a
//! full trace than no memory at all (BENCHMARKS.md, the ray budget's
//! fifteenth part).
//!
//! The time a step poses is the server's clock, stepped by whatever `dt`
//! it is given, so the same slot of two rounds need not pose alike: at
//! steps of an f32 1/60 s a 1.25 s loop drifts 65 ns a round. A
//! remembered AO verifies only while the times lie within the tolerance;
//! past it the point waits out its due and its trace is remembered
//! afresh. Each animation's time within its loop is taken from the f64
//! clock ([`Scene::pose_into_at`](crate::Scene::pose_into_at)), so a
//! server running for days verifies as in its first minute; its f32
//! rounding (under 1.2 us for a loop of 20 s) is allowed for at a jump
//! ([`JUMP_MARGIN`]).
//!
//! Memory is capped ([`PipelineConfig::loop_memory_bytes`], every array
//! it holds counted: the slots, 4 bytes each, and per instance an index
//! to them, 4 bytes a point up to the last remembered): a new point is
//! remembered only while room for all its slots is left, and no slot is
//! learnt past the cap. It is dropped when an instance is
//! placed by hand ([`Pipeline::place_instance`]), which breaks the loop.
//!
//! [`PipelineConfig::loop_memory_bytes`]: super::config::PipelineConfig::loop_memory_bytes
//! [`Pipeline::place_instance`]: super::Pipeline::place_instance

use crate::model::animation::{Animation, Interpolation};

/// The longest loop remembered, in seconds.
pub const LOOP_LONGEST: f32 = 20.0;

/// The most slots a loop is cut into.
pub const MAX_SLOTS: u32 = 1200;

/// How far apart in animation time (seconds) a remembered trace's pose and
/// a step's may be for the trace to verify the step's (see the module):
/// 0.1 ms, a 167th of a step at 60 Hz, in which a part moving at 1 m/s
/// moves 0.1 mm.
pub const VERIFY_TOLERANCE: f64 = 1e-4;

/// The most places in a loop where its pose may jump (an
/// animation's start, a key of a step interpolation) for which traces are
/// verified (past them, none is).
const MAX_JUMPS: usize = 1 << 16;

/// The time within its slot a trace was made at, as a share of the slot
/// from its start, is kept in this many steps (16 bits: 0.25 us at
/// 60 Hz).
const OFFSET_STEPS: f64 = 65535.0;

/// The bit that marks a slot traced (the others: the time within the
/// slot in the low 16 bits, the AO in the 8 above, and the round it was
/// traced in, modulo 128, in the 7 above those).
const KNOWN: u32 = 1 << 31;

/// How near a jump, in [`OFFSET_STEPS`] of a slot (4 us at 60 Hz), a
/// step counts as on it (none verifies), and a trace as maybe on its far
/// side (it verifies no step): above the rounding of an animation's time
/// within its loop to f32 (1.2 us for a loop of 20 s) and of the two
/// ways a step's time and the jump's are found (1e-14 of a slot), far
/// below the tolerance.
const JUMP_MARGIN: f64 = 16.0;

/// No row: the point is not remembered.
const NO_ROW: u32 = u32::MAX;

/// A moment of the scene's loop: its slot, its round (modulo 128), the
/// time within its slot, and which times within the slot a remembered
/// trace verifies at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Moment {
    /// The slot of the loop.
    pub slot: u32,
    /// The round, modulo 128.
    pub round: u16,
    /// The time within the slot, in [`OFFSET_STEPS`] from its start.
    pub offset: u16,
    /// The times within the slot (inclusive, as `offset`) of a trace that
    /// verifies now: within [`VERIFY_TOLERANCE`] and no jump of the pose
    /// between; empty (`lo > hi`) where none does.
    pub verifies: (u16, u16),
}

/// Per point, its AO at the slots of the scene's loop it was traced in.
#[derive(Debug)]
pub(super) struct LoopMemory {
    /// The loop's period in seconds.
    period: f64,
    /// The slots it is cut into.
    slots: u32,
    /// The most bytes its arrays may hold (their capacity): past them no
    /// new point is remembered, and a remembered one learns no slot that
    /// would need more.
    max_bytes: u64,
    /// Bytes its arrays hold (their capacity, `rows`' and `by_slot`'s).
    held: u64,
    /// Where the scene's pose may jump within the loop (seconds from its
    /// start, ascending; [`jumps`]), where the pose is a
    /// function of the time within the loop; `None` where it is not (or
    /// where verifying is off): no trace verifies.
    jumps: Option<Vec<f64>>,
    /// By instance, by point, its row in `by_slot` ([`NO_ROW`]: none):
    /// an array, not a map, as a step looks up tens of thousands of
    /// points in key order.
    rows: Vec<Vec<u32>>,
    /// Points remembered (rows given).
    remembered: usize,
    /// Per slot, by row, the quantized AO, the round and the time within
    /// the slot the point was traced at, with [`KNOWN`] (0, or past the
    /// end: not traced there). Slot by slot, so that a step, which looks
    /// at one slot only, reads one short array.
    by_slot: Vec<Vec<u32>>,
}

/// What the loop memory holds of a point at a moment of the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Recall {
    /// Its AO traced at the moment's slot (quantized).
    pub ao: u8,
    /// Whether that trace was in an earlier round than the moment's
    /// (modulo 128): it predicts the moment's AO (the ranking rule of the
    /// module).
    pub earlier: bool,
    /// Whether that trace verifies the moment's pose (the verifying rule
    /// of the module).
    pub verifies: bool,
}

/// Where the pose of a scene whose animations are `animations` may jump
/// within a loop of `period` seconds, ascending: each animation's start
/// (and so the loop's), where its end does not pose as its start does
/// ([`Animation::wraps_smoothly`]), and each key of a step interpolation,
/// in every round of the animation within the loop. `None` where the
/// loop's time does not fix the pose: an animation whose duration does
/// not divide `period` exactly (its time would drift against the loop's
/// round by round), or too many jumps to keep.
pub(super) fn jumps(period: f64, animations: &[Animation]) -> Option<Vec<f64>> {
    let mut out = Vec::new();
    for a in animations {
        let d = a.duration() as f64;
        if !(d.is_finite() && d > 0.0) {
            // Posed at its start whatever the time.
            continue;
        }
        let m = (period / d).round();
        if !(m >= 1.0 && m * d == period && m as usize <= MAX_JUMPS) {
            return None;
        }
        let steps: Vec<f64> = a
            .channels
            .iter()
            .filter(|c| c.interpolation == Interpolation::Step)
            .flat_map(|c| c.times.iter().map(|&t| t as f64))
            .collect();
        let restarts = !a.wraps_smoothly();
        for k in 0..m as usize {
            if restarts {
                out.push(k as f64 * d);
            }
            out.extend(steps.iter().map(|t| k as f64 * d + t));
            if out.len() > MAX_JUMPS {
                return None;
            }
        }
    }
    out.retain(|&x| (0.0..period).contains(&x));
    out.sort_by(f64::total_cmp);
    out.dedup();
    Some(out)
}

impl LoopMemory {
    /// A memory of a loop of `period` seconds (positive, finite, at least
    /// two steps at 60 Hz) holding at most `max_bytes`, whose traces verify
    /// a step's pose where `jumps` ([`jumps`]) says where the pose jumps
    /// (`None`: none verifies); `None` where the loop is shorter (its
    /// moments cannot be told apart) or not even one point fits.
    pub fn new(period: f32, max_bytes: u64, jumps: Option<Vec<f64>>) -> Option<LoopMemory> {
        if !(period.is_finite() && period * 60.0 >= 2.0) {
            return None;
        }
        let slots = ((period as f64 * 60.0).round() as u32).clamp(2, MAX_SLOTS);
        (max_bytes >= Self::point_bytes(slots)).then(|| LoopMemory {
            period: period as f64,
            slots,
            max_bytes,
            held: 0,
            jumps,
            rows: Vec::new(),
            remembered: 0,
            by_slot: vec![Vec::new(); slots as usize],
        })
    }

    /// Bytes one point's slots take.
    fn point_bytes(slots: u32) -> u64 {
        slots as u64 * 4
    }

    /// Point `key`'s row, if it has one.
    fn row(&self, key: u64) -> Option<usize> {
        let row = *self
            .rows
            .get((key >> 32) as usize)?
            .get(key as u32 as usize)?;
        (row != NO_ROW).then_some(row as usize)
    }

    /// The moment of scene time `t` (seconds; the time the scene is posed
    /// at): its slot of the loop, its round, the time within the slot,
    /// and which remembered traces verify at it.
    pub fn moment(&self, t: f64) -> Moment {
        let rounds = (t / self.period).max(0.0);
        let at = rounds.fract() * self.slots as f64;
        let slot = at.round() as u64;
        // The last slot's second half is the next round's first slot.
        let round = rounds.floor() as u64 + slot / self.slots as u64;
        let slot = (slot % self.slots as u64) as u32;
        // From -0.5 (the slot's start) to 0.5 (its end).
        let within = (at - at.round()).clamp(-0.5, 0.5);
        Moment {
            slot,
            round: (round % 128) as u16,
            offset: ((within + 0.5) * OFFSET_STEPS).round() as u16,
            verifies: self.verifies(slot, within),
        }
    }

    /// The times within slot `slot` (as [`Moment::offset`]) of a trace
    /// that verifies a step at `within` of the slot (-0.5 its start, 0.5
    /// its end): within [`VERIFY_TOLERANCE`] of it and no jump of the pose
    /// between (a trace whose quantized time could lie on the jump's far
    /// side is left out).
    fn verifies(&self, slot: u32, within: f64) -> (u16, u16) {
        const NONE: (u16, u16) = (1, 0);
        let Some(jumps) = &self.jumps else {
            return NONE;
        };
        let width = self.period / self.slots as f64;
        let now = (within + 0.5) * OFFSET_STEPS;
        let tolerance = VERIFY_TOLERANCE / width * OFFSET_STEPS;
        let (mut lo, mut hi) = (now - tolerance, now + tolerance);
        // The jumps within a slot of this one's middle, as times within
        // it (the loop's start lies in its first slot).
        let middle = slot as f64 * width;
        for &x in jumps {
            let mut d = x - middle;
            if d > self.period / 2.0 {
                d -= self.period;
            } else if d <= -self.period / 2.0 {
                d += self.period;
            }
            let within_jump = d / width;
            if within_jump.abs() > 0.5 + 2.0 * JUMP_MARGIN / OFFSET_STEPS {
                continue;
            }
            let q = (within_jump + 0.5) * OFFSET_STEPS;
            // A step on the jump (to rounding) may pose as after it or
            // before it: none verifies.
            if ((within + 0.5) * OFFSET_STEPS - q).abs() <= JUMP_MARGIN {
                return NONE;
            } else if within < within_jump {
                hi = hi.min(q - JUMP_MARGIN);
            } else {
                lo = lo.max(q + JUMP_MARGIN);
            }
        }
        let (lo, hi) = (lo.ceil().max(0.0), hi.floor().min(OFFSET_STEPS));
        if lo > hi {
            return NONE;
        }
        (lo as u16, hi as u16)
    }

    /// Notes that point `key` traced to `ao` (quantized) at moment `at`
    /// (not where that would take the memory past its bytes).
    pub fn note(&mut self, key: u64, at: Moment, ao: u8) {
        let slot = at.slot as usize;
        if slot >= self.by_slot.len() {
            return;
        }
        let row = match self.row(key) {
            Some(row) => row,
            None => {
                let (i, k) = ((key >> 32) as usize, key as u32 as usize);
                // A new point: its row in the instance's index, which must
                // fit, and room left for its slots.
                let room = self.max_bytes.saturating_sub(self.held);
                let row = self.remembered;
                if row >= NO_ROW as usize || room < Self::point_bytes(self.slots) {
                    return;
                }
                if self.rows.len() <= i {
                    self.rows.resize(i + 1, Vec::new());
                }
                if !grow(&mut self.rows[i], k, NO_ROW, self.max_bytes, &mut self.held) {
                    return;
                }
                self.rows[i][k] = row as u32;
                self.remembered += 1;
                row
            }
        };
        if grow(
            &mut self.by_slot[slot],
            row,
            0,
            self.max_bytes,
            &mut self.held,
        ) {
            self.by_slot[slot][row] =
                KNOWN | u32::from(at.round) << 24 | u32::from(ao) << 16 | u32::from(at.offset);
        }
    }

    /// What the memory holds of point `key` at moment `at`'s slot: its AO
    /// there, and whether it predicts and verifies `at` (one look-up for
    /// both).
    pub fn recall(&self, key: u64, at: Moment) -> Option<Recall> {
        let row = self.row(key)?;
        let v = *self.by_slot.get(at.slot as usize)?.get(row)?;
        if v & KNOWN == 0 {
            return None;
        }
        let (lo, hi) = at.verifies;
        Some(Recall {
            ao: (v >> 16) as u8,
            earlier: (v >> 24) & 0x7f != u32::from(at.round),
            verifies: (lo..=hi).contains(&(v as u16)),
        })
    }

    /// Point `key`'s AO at moment `at`'s slot in an earlier round (not in
    /// `at`'s own round, where the slot spans several steps: a trace a
    /// step ago says nothing of the loop).
    #[cfg(test)]
    pub fn predict(&self, key: u64, at: Moment) -> Option<u8> {
        self.recall(key, at).filter(|r| r.earlier).map(|r| r.ao)
    }

    /// Point `key`'s AO traced at a pose that verifies moment `at`'s (see
    /// the module): at `at`'s slot, in any round, at a time within it
    /// that `at` admits.
    #[cfg(test)]
    pub fn verify(&self, key: u64, at: Moment) -> Option<u8> {
        self.recall(key, at).filter(|r| r.verifies).map(|r| r.ao)
    }

    /// The loop's period in seconds.
    pub fn period(&self) -> f32 {
        self.period as f32
    }

    /// The points remembered.
    pub fn len(&self) -> usize {
        self.remembered
    }

    /// Bytes it holds.
    pub fn memory_bytes(&self) -> u64 {
        self.held
    }
}

/// Makes `v` long enough to hold index `at` (new entries `fill`), its
/// capacity grown by doubling where `held` bytes (the memory's arrays')
/// stay within `max`, else by as little as `at` needs; `false` (nothing
/// changed) where even that would pass `max`.
fn grow(v: &mut Vec<u32>, at: usize, fill: u32, max: u64, held: &mut u64) -> bool {
    if at < v.len() {
        return true;
    }
    let before = v.capacity();
    if at >= before {
        let room = max.saturating_sub(*held) / 4;
        let Some(least) = (at + 1).checked_sub(before).filter(|&n| n as u64 <= room) else {
            return false;
        };
        let doubled = (v.len() * 2).max(at + 1).max(16) - before;
        let extra = if doubled as u64 <= room {
            doubled
        } else {
            least
        };
        v.reserve_exact(at + 1 - v.len() + (extra - least));
        *held += (v.capacity() - before) as u64 * 4;
    }
    v.resize(at + 1, fill);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_predicted_by_the_same_moment_of_an_earlier_round() {
        let mut m = LoopMemory::new(2.0, 1 << 20, None).unwrap();
        let slot_round = |t: f64| {
            let at = m.moment(t);
            (at.slot, at.round)
        };
        assert_eq!(slot_round(0.0), (0, 0));
        assert_eq!(slot_round(2.0 + 1.0 / 60.0), (1, 1));
        // Just short of a round's end is the next round's first slot.
        assert_eq!(slot_round(4.0 - 1e-9), (0, 2));
        let (half, later) = (m.moment(0.5), m.moment(0.6));
        let (next, next_later) = (m.moment(2.5), m.moment(2.6));
        let (beside, far) = (m.moment(2.5 + 1.0 / 60.0), m.moment(200.5));
        assert_eq!(m.predict(7, half), None);
        m.note(7, half, 200);
        m.note(7, later, 10);
        // Not within the round it was traced in.
        assert_eq!(m.predict(7, half), None);
        // A round later the same moment, not the next slot.
        assert_eq!(m.predict(7, next), Some(200));
        assert_eq!(m.predict(7, next_later), Some(10));
        assert_eq!(m.predict(7, beside), None);
        // Or any later round.
        assert_eq!(m.predict(7, far), Some(200));
        assert_eq!(m.predict(8, next), None);
        // Open (255) is remembered too, and the loop's end is its start.
        let (start, end) = (m.moment(0.0), m.moment(4.0 - 1e-9));
        m.note(8, start, 255);
        assert_eq!(m.predict(8, end), Some(255));
        // A trace in a later round takes the slot's place.
        m.note(7, next, 100);
        assert_eq!(m.predict(7, far), Some(100));
    }

    #[test]
    fn past_its_cap_no_new_point_is_remembered() {
        let per_point = LoopMemory::point_bytes(120);
        let cap = per_point * 3;
        let mut m = LoopMemory::new(2.0, cap, None).unwrap();
        let (now, soon) = (m.moment(0.1), m.moment(0.2));
        let (later, later_soon) = (m.moment(2.1), m.moment(2.2));
        for key in 0..1000 {
            m.note(key, now, key as u8);
        }
        // Points are remembered while room is left for their slots.
        let kept = m.len() as u64;
        assert!(kept > 3 && kept < 1000, "{kept}");
        assert!(m.memory_bytes() <= cap, "{}", m.memory_bytes());
        // Those remembered still learn new slots.
        m.note(1, soon, 99);
        assert_eq!(m.predict(1, later_soon), Some(99));
        assert_eq!(m.predict(2, later), Some(2));
        assert_eq!(m.predict(999, later), None);
        // A point far down an instance needs the row index to reach it:
        // not where that passes the cap.
        let mut far = LoopMemory::new(2.0, cap, None).unwrap();
        far.note(1 << 20, now, 5);
        assert_eq!((far.len(), far.predict(1 << 20, later)), (0, None));
        assert!(far.memory_bytes() <= cap);
        // Every slot of fifty points does not fit forty points' bytes:
        // the slots past the cap are not learnt, and nothing passes it.
        let mut full = LoopMemory::new(2.0, per_point * 40, None).unwrap();
        for slot in 0..120 {
            for key in 0..50 {
                full.note(key, full.moment(slot as f64 / 60.0), 1);
            }
        }
        assert!(
            full.memory_bytes() <= per_point * 40,
            "{}",
            full.memory_bytes()
        );
        let learnt = (0..120)
            .filter(|&slot| {
                full.predict(0, full.moment(2.0 + slot as f64 / 60.0))
                    .is_some()
            })
            .count();
        assert!(learnt > 0 && learnt < 120, "{learnt}");
        assert!(LoopMemory::new(2.0, per_point - 1, None).is_none());
        assert!(LoopMemory::new(0.0, 1 << 20, None).is_none());
        assert!(LoopMemory::new(f32::NAN, 1 << 20, None).is_none());
    }

    #[test]
    fn a_loop_is_cut_into_steps_at_60_hz_and_at_most_max_slots() {
        assert_eq!(
            LoopMemory::new(LOOP_LONGEST, 1 << 30, None).unwrap().slots,
            1200
        );
        assert_eq!(LoopMemory::new(1.25, 1 << 30, None).unwrap().slots, 75);
        let m = LoopMemory::new(100.0, 1 << 30, None).unwrap();
        assert_eq!(m.slots, MAX_SLOTS);
        for t in [0.0, 1.0, 100.0 - 1e-6, 1e6] {
            assert!(m.moment(t).slot < MAX_SLOTS);
        }
        // Under two steps its moments cannot be told apart.
        assert!(LoopMemory::new(1.0 / 60.0, 1 << 30, None).is_none());
        assert!(LoopMemory::new(-1.0, 1 << 30, None).is_none());
        assert_eq!(LoopMemory::new(2.0 / 60.0, 1 << 30, None).unwrap().slots, 2);
    }

    #[test]
    fn a_trace_verifies_the_same_time_of_any_round_with_no_jump_between() {
        // A loop of 2 s (120 slots of 1/60 s) whose pose jumps at its
        // start and half way (an animation of 1 s).
        let anim = crate::model::animation::Animation::translation(
            "slide",
            0,
            &[(0.0, glam::Vec3::ZERO), (1.0, glam::Vec3::X)],
        );
        let jumped = jumps(2.0, std::slice::from_ref(&anim)).unwrap();
        assert_eq!(jumped, vec![0.0, 1.0]);
        let mut m = LoopMemory::new(2.0, 1 << 20, Some(jumped)).unwrap();
        let t = 0.25;
        m.note(7, m.moment(t), 90);
        // The same time in this round and later ones, to the tolerance.
        for dt in [
            0.0,
            2.0,
            20.0,
            2.0 + 0.9 * VERIFY_TOLERANCE,
            4.0 - 0.9 * VERIFY_TOLERANCE,
        ] {
            assert_eq!(m.verify(7, m.moment(t + dt)), Some(90), "{dt}");
        }
        // Not past the tolerance, nor in another slot, nor another point.
        for dt in [
            2.0 + 1.2 * VERIFY_TOLERANCE,
            2.0 - 1.2 * VERIFY_TOLERANCE,
            2.0 + 1.0 / 60.0,
        ] {
            assert_eq!(m.verify(7, m.moment(t + dt)), None, "{dt}");
        }
        assert_eq!(m.verify(8, m.moment(t + 2.0)), None);
        // Never across a jump: the loop's start (in its first slot) and
        // the animation's second start (slot 60), however near in time.
        let near = 0.3 * VERIFY_TOLERANCE;
        for jump in [0.0, 1.0] {
            let key = 10 + jump as u64;
            m.note(key, m.moment(2.0 + jump - near), 30);
            assert_eq!(m.verify(key, m.moment(4.0 + jump - near / 2.0)), Some(30));
            assert_eq!(m.verify(key, m.moment(4.0 + jump + near)), None, "{jump}");
            m.note(key + 100, m.moment(2.0 + jump + near), 40);
            assert_eq!(
                m.verify(key + 100, m.moment(4.0 + jump + near / 2.0)),
                Some(40)
            );
            assert_eq!(
                m.verify(key + 100, m.moment(4.0 + jump - near)),
                None,
                "{jump}"
            );
        }
        // A step exactly on a jump whose two sums round apart (a 1.25 s
        // loop of a 0.25 s animation, at 1.5 s: the jump at 0.25 s) is on
        // neither side: a trace just before the jump does not verify it.
        let quarter = crate::model::animation::Animation::translation(
            "q",
            0,
            &[(0.0, glam::Vec3::ZERO), (0.25, glam::Vec3::X)],
        );
        let at_quarters = jumps(1.25, std::slice::from_ref(&quarter)).unwrap();
        assert_eq!(at_quarters, vec![0.0, 0.25, 0.5, 0.75, 1.0]);
        let mut q = LoopMemory::new(1.25, 1 << 20, Some(at_quarters)).unwrap();
        for (before, on) in [(0.25, 1.5), (0.5, 1.75), (0.25, 2.75)] {
            q.note(3, q.moment(before - 0.5 * VERIFY_TOLERANCE), 60);
            assert_eq!(q.verify(3, q.moment(on)), None, "{on}");
            assert_eq!(q.moment(on).verifies, (1, 0), "{on}");
        }
        // A memory that does not verify (verifying off, or a pose not
        // fixed by the loop's time) still predicts.
        let mut off = LoopMemory::new(2.0, 1 << 20, None).unwrap();
        off.note(7, off.moment(t), 90);
        assert_eq!(off.verify(7, off.moment(t + 2.0)), None);
        assert_eq!(off.predict(7, off.moment(t + 2.0)), Some(90));
    }

    #[test]
    fn the_pose_jumps_at_each_start_and_step_key_and_is_not_fixed_by_a_loop_its_durations_miss() {
        use crate::model::animation::{Animation, Interpolation};
        use glam::Vec3;
        let mut stepped =
            Animation::translation("s", 0, &[(0.0, Vec3::ZERO), (0.1, Vec3::X), (0.5, Vec3::Y)]);
        stepped.channels[0].interpolation = Interpolation::Step;
        // Two rounds of the stepped one (0.5 s) in a loop of 1 s.
        assert_eq!(
            jumps(1.0, std::slice::from_ref(&stepped)).unwrap(),
            vec![0.0, 0.1f32 as f64, 0.5, 0.5 + 0.1f32 as f64]
        );
        // Linear keys jump only where the animation starts again.
        let linear = Animation::translation("l", 0, &[(0.0, Vec3::ZERO), (0.25, Vec3::X)]);
        assert_eq!(
            jumps(0.5, std::slice::from_ref(&linear)).unwrap(),
            vec![0.0, 0.25]
        );
        // A duration that does not divide the loop exactly (in f32, 0.3 s
        // three times is not 0.9 s): its pose drifts against the loop.
        let third = Animation::translation("t", 0, &[(0.0, Vec3::ZERO), (0.3, Vec3::X)]);
        assert_eq!(jumps(0.9f32 as f64, &[third]), None);
        // A wheel turning a whole turn a loop, or a part going there and
        // back, poses alike at its end and its start: no jump there, and
        // a trace verifies across the loop's start.
        let turns = |angles: &[f32]| {
            let mut a = Animation::translation("w", 0, &[(0.0, Vec3::ZERO)]);
            a.channels[0].times = (0..angles.len()).map(|k| k as f32 * 0.25).collect();
            a.channels[0].keys = crate::model::animation::Keys::Rotation(
                angles
                    .iter()
                    .map(|&r| glam::Quat::from_rotation_x(r))
                    .collect(),
            );
            a
        };
        let pi = std::f32::consts::PI;
        let wheel = turns(&[0.0, pi, 2.0 * pi]);
        assert!(wheel.wraps_smoothly() && !turns(&[0.0, pi]).wraps_smoothly());
        // A turn short by a tenth of a degree is a jump.
        assert!(!turns(&[0.0, pi, 2.0 * pi - 0.1f32.to_radians()]).wraps_smoothly());
        let back = Animation::translation(
            "b",
            0,
            &[(0.0, Vec3::ZERO), (0.25, Vec3::X), (0.5, Vec3::ZERO)],
        );
        assert!(back.wraps_smoothly());
        assert_eq!(
            jumps(1.0, &[wheel.clone(), back]).unwrap(),
            Vec::<f64>::new()
        );
        let mut m = LoopMemory::new(1.0, 1 << 20, jumps(1.0, &[wheel])).unwrap();
        m.note(5, m.moment(1.0 - 0.3 * VERIFY_TOLERANCE), 70);
        assert_eq!(
            m.verify(5, m.moment(2.0 + 0.3 * VERIFY_TOLERANCE)),
            Some(70)
        );
        // An animation of no duration poses alike at every time.
        let still = Animation::translation("z", 0, &[(0.0, Vec3::X)]);
        assert_eq!(jumps(0.5, &[linear, still]).unwrap(), vec![0.0, 0.25]);
    }
}
