//! The loop memory (issue 20): where a scene's animation loops, a
//! point's AO at a moment of the loop is what it was at that moment of an
//! earlier round, so what it was then predicts what it is now.
//!
//! Every animation of a scene loops over its own duration
//! ([`Scene::loop_period`](crate::Scene::loop_period) finds the shortest
//! time after which all of them start again together). The memory keeps,
//! per point traced under a ray budget, its quantized AO at each slot of
//! the loop it was traced in (a slot is one step of the loop at 60 Hz, or
//! a [`MAX_SLOTS`]-th of a loop longer than 20 s). When the budget ranks a
//! point whose AO at the same slot of an earlier round would not be sent
//! against what clients hold, it ranks as one with nothing to send
//! (urgency 0: only the share of its rays motion reached and its wait
//! rank it, as for a point without a trend), below the points that
//! changed. A point the memory knows nothing of, or whose remembered AO
//! would be sent, ranks by its trend as before. Nothing is sent from the
//! memory: it only orders the points the budget traces, and every point
//! is still traced by its due. A wrong prediction (where a loop's end
//! jumps, float noise between rounds, a server running for days, whose
//! f32 pose time then lags its clock by milliseconds) delays a point to
//! its due at most.
//!
//! Predicting only *nothing to send*, and leaving the points that would
//! be sent to their trends, is measured to be the safer rule:
//! promoting those too (urgency from the remembered AO) traced fewer,
//! dearer points under demand beyond the budget and left more points off a
//! full trace than no memory at all (BENCHMARKS.md, the ray budget's
//! fifteenth part).
//!
//! Memory is capped ([`PipelineConfig::loop_memory_bytes`], counted as
//! the slots and a map entry a point, so about that much): past the cap
//! no further point is remembered. It is dropped when an instance is
//! placed by hand ([`Pipeline::place_instance`]), which breaks the loop.
//!
//! [`PipelineConfig::loop_memory_bytes`]: super::config::PipelineConfig::loop_memory_bytes
//! [`Pipeline::place_instance`]: super::Pipeline::place_instance

use rustc_hash::FxHashMap;

/// The longest loop remembered, in seconds.
pub const LOOP_LONGEST: f32 = 20.0;

/// The most slots a loop is cut into.
pub const MAX_SLOTS: u32 = 1200;

/// The bit that marks a slot traced (the others: the AO in the low 8
/// bits, the round it was traced in, modulo 128, in the 7 above).
const KNOWN: u16 = 1 << 15;

/// A moment of the scene's loop: its slot, and the round (modulo 128).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Moment {
    /// The slot of the loop.
    pub slot: u32,
    /// The round, modulo 128.
    pub round: u16,
}

/// Per point, its AO at the slots of the scene's loop it was traced in.
#[derive(Debug)]
pub(super) struct LoopMemory {
    /// The loop's period in seconds.
    period: f64,
    /// The slots it is cut into.
    slots: u32,
    /// Points past which no new one is remembered.
    max_points: usize,
    /// By point key, per slot, the quantized AO and the round it was
    /// traced in, with [`KNOWN`] (0: not traced there).
    points: FxHashMap<u64, Box<[u16]>>,
}

impl LoopMemory {
    /// A memory of a loop of `period` seconds (positive, finite, at least
    /// two steps at 60 Hz) holding about `max_bytes`; `None` where the loop
    /// is shorter (its moments cannot be told apart) or not even one point
    /// fits.
    pub fn new(period: f32, max_bytes: u64) -> Option<LoopMemory> {
        if !(period.is_finite() && period * 60.0 >= 2.0) {
            return None;
        }
        let slots = ((period as f64 * 60.0).round() as u32).clamp(2, MAX_SLOTS);
        let per_point = Self::point_bytes(slots);
        let max_points = usize::try_from(max_bytes / per_point).unwrap_or(usize::MAX);
        (max_points > 0).then(|| LoopMemory {
            period: period as f64,
            slots,
            max_points,
            points: FxHashMap::default(),
        })
    }

    /// Bytes one remembered point takes, with the map's share.
    fn point_bytes(slots: u32) -> u64 {
        slots as u64 * 2 + std::mem::size_of::<(u64, Box<[u16]>)>() as u64 + 8
    }

    /// The moment of scene time `t` (seconds; the time the scene is posed
    /// at): its slot of the loop, and its round.
    pub fn moment(&self, t: f64) -> Moment {
        let rounds = (t / self.period).max(0.0);
        let slot = (rounds.fract() * self.slots as f64).round() as u64;
        // The last slot's second half is the next round's first slot.
        let round = rounds.floor() as u64 + slot / self.slots as u64;
        Moment {
            slot: (slot % self.slots as u64) as u32,
            round: (round % 128) as u16,
        }
    }

    /// Notes that point `key` traced to `ao` (quantized) at moment `at`.
    pub fn note(&mut self, key: u64, at: Moment, ao: u8) {
        let full = self.points.len() >= self.max_points;
        let slots = self.slots as usize;
        let entry = match self.points.get_mut(&key) {
            Some(e) => e,
            None if full => return,
            None => self
                .points
                .entry(key)
                .or_insert_with(|| vec![0; slots].into_boxed_slice()),
        };
        if let Some(s) = entry.get_mut(at.slot as usize) {
            *s = KNOWN | at.round << 8 | ao as u16;
        }
    }

    /// Point `key`'s AO at moment `at`'s slot in an earlier round (not in
    /// `at`'s own round, where the slot spans several steps: a trace a
    /// step ago says nothing of the loop).
    pub fn predict(&self, key: u64, at: Moment) -> Option<u8> {
        match self.points.get(&key)?.get(at.slot as usize) {
            Some(&v) if v & KNOWN != 0 && (v >> 8) & 0x7f != at.round => Some(v as u8),
            _ => None,
        }
    }

    /// The loop's period in seconds.
    pub fn period(&self) -> f32 {
        self.period as f32
    }

    /// The points remembered.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Bytes it holds.
    pub fn memory_bytes(&self) -> u64 {
        let slot = std::mem::size_of::<(u64, Box<[u16]>)>() as u64 + 8;
        self.points.capacity() as u64 * slot + self.points.len() as u64 * self.slots as u64 * 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_is_predicted_by_the_same_moment_of_an_earlier_round() {
        let mut m = LoopMemory::new(2.0, 1 << 20).unwrap();
        assert_eq!(m.moment(0.0), Moment { slot: 0, round: 0 });
        assert_eq!(m.moment(2.0 + 1.0 / 60.0), Moment { slot: 1, round: 1 });
        // Just short of a round's end is the next round's first slot.
        assert_eq!(m.moment(4.0 - 1e-9), Moment { slot: 0, round: 2 });
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
        let mut m = LoopMemory::new(2.0, per_point * 3).unwrap();
        let (now, soon) = (m.moment(0.1), m.moment(0.2));
        let (later, later_soon) = (m.moment(2.1), m.moment(2.2));
        for key in 0..10 {
            m.note(key, now, key as u8);
        }
        assert_eq!(m.len(), 3);
        // Those remembered still learn new slots.
        m.note(1, soon, 99);
        assert_eq!(m.predict(1, later_soon), Some(99));
        assert_eq!(m.predict(2, later), Some(2));
        assert_eq!(m.predict(9, later), None);
        assert!(m.memory_bytes() >= 3 * per_point);
        assert!(LoopMemory::new(2.0, per_point - 1).is_none());
        assert!(LoopMemory::new(0.0, 1 << 20).is_none());
        assert!(LoopMemory::new(f32::NAN, 1 << 20).is_none());
    }

    #[test]
    fn a_loop_is_cut_into_steps_at_60_hz_and_at_most_max_slots() {
        assert_eq!(LoopMemory::new(LOOP_LONGEST, 1 << 30).unwrap().slots, 1200);
        assert_eq!(LoopMemory::new(1.25, 1 << 30).unwrap().slots, 75);
        let m = LoopMemory::new(100.0, 1 << 30).unwrap();
        assert_eq!(m.slots, MAX_SLOTS);
        for t in [0.0, 1.0, 100.0 - 1e-6, 1e6] {
            assert!(m.moment(t).slot < MAX_SLOTS);
        }
        // Under two steps its moments cannot be told apart.
        assert!(LoopMemory::new(1.0 / 60.0, 1 << 30).is_none());
        assert!(LoopMemory::new(-1.0, 1 << 30).is_none());
        assert_eq!(LoopMemory::new(2.0 / 60.0, 1 << 30).unwrap().slots, 2);
    }
}
