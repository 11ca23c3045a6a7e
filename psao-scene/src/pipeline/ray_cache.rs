//! Ray scores kept from static points' last traces, so a point that motion
//! reaches re-traces only its reached rays: its AO is then added up from
//! the kept and the new scores in the tracer's own order
//! ([`ao_of_scores`](crate::trace::ao::ao_of_scores)), the same bits a full
//! trace gives.
//!
//! Only points of static instances are kept (a moving instance's rays all
//! move), only after they were first traced near motion, and only up to a
//! byte cap; a point without scores is traced in full. A point that must
//! wait (the ray budget) keeps its scores and remembers which rays motion
//! reached meanwhile (`stale`; a point planned late, up to the step it was
//! last planned in, the rest found when the budget takes it); a point put
//! aside by culling loses them.

use super::reach::RayMask;
use super::slots::PointSlots;
use glam::Vec4;

/// One point's kept scores.
#[derive(Clone, Debug)]
pub struct Entry {
    /// Each ray's score as last traced (or, for the rays in `stale`, as
    /// traced before motion reached them).
    pub scores: Box<[f32]>,
    /// Rays motion reached since they were traced (for a point planned
    /// late, up to the step it was last planned in).
    pub stale: RayMask,
    /// Each ray's unit direction and length (`w`), as
    /// [`PointRays::ray`](crate::trace::ao::PointRays::ray) gives them: a
    /// static point's rays never change, and the reach test reads them
    /// here instead of drawing them again.
    pub rays: Box<[Vec4]>,
}

/// The kept scores of points, by (instance, point).
#[derive(Debug)]
pub struct RayCache {
    rays: u32,
    max_entries: usize,
    /// Per point, its entry's index plus one (0: none).
    slots: PointSlots,
    /// The entries, those at `free` unused (kept for the next point).
    entries: Vec<Entry>,
    free: Vec<u32>,
}

/// Bytes one entry of `rays` rays takes, with its slot's share.
fn entry_bytes(rays: u32) -> u64 {
    rays as u64 * 20 + (rays as u64).div_ceil(64) * 8 + 64
}

/// The key of point `k` of instance `i`.
pub fn key(i: usize, k: u32) -> u64 {
    ((i as u64) << 32) | k as u64
}

impl RayCache {
    /// A cache of points with `rays` rays, holding at most `max_bytes`.
    pub fn new(rays: u32, max_bytes: u64) -> RayCache {
        RayCache {
            rays,
            max_entries: (max_bytes / entry_bytes(rays)).min(u32::MAX as u64 - 1) as usize,
            slots: PointSlots::default(),
            entries: Vec::new(),
            free: Vec::new(),
        }
    }

    /// A point's entry.
    pub fn get(&self, key: u64) -> Option<&Entry> {
        match self.slots.get(key) {
            0 => None,
            n => self.entries.get(n as usize - 1),
        }
    }

    /// Whether a new point would be stored (the cache is not full).
    pub fn has_room(&self) -> bool {
        self.len() < self.max_entries
    }

    /// Stores a point's fresh scores (its stale rays cleared), with its
    /// rays (`rays()` is called only for a point not held yet). A new point
    /// is not stored once the cache is full; returns whether it is held.
    pub fn store(&mut self, key: u64, scores: &[f32], rays: impl FnOnce() -> Vec<Vec4>) -> bool {
        if let Some(e) = self
            .slots
            .get(key)
            .checked_sub(1)
            .map(|n| &mut self.entries[n as usize])
        {
            e.scores.copy_from_slice(scores);
            e.stale = RayMask::none(self.rays);
            return true;
        }
        if !self.has_room() || scores.len() != self.rays as usize {
            return false;
        }
        let rays = rays();
        if rays.len() != scores.len() {
            return false;
        }
        let entry = Entry {
            scores: scores.into(),
            stale: RayMask::none(self.rays),
            rays: rays.into(),
        };
        let at = match self.free.pop() {
            Some(n) => {
                self.entries[n as usize] = entry;
                n
            }
            None => {
                self.entries.push(entry);
                self.entries.len() as u32 - 1
            }
        };
        self.slots.set(key, at + 1);
        true
    }

    /// Marks rays of a waiting point as reached by motion. Returns whether
    /// the point has an entry.
    pub fn mark_stale(&mut self, key: u64, reached: &RayMask) -> bool {
        match self.slots.get(key) {
            0 => false,
            n => {
                self.entries[n as usize - 1].stale.union(reached);
                true
            }
        }
    }

    /// Forgets a point's scores (it will be traced in full).
    pub fn forget(&mut self, key: u64) {
        let n = self.slots.get(key);
        if n != 0 {
            self.slots.set(key, 0);
            self.free.push(n - 1);
        }
    }

    /// Points held.
    pub fn len(&self) -> usize {
        self.entries.len() - self.free.len()
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.entries.capacity() as u64 * entry_bytes(self.rays)
            + self.free.capacity() as u64 * 4
            + self.slots.memory_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stores_up_to_the_cap_and_tracks_stale_rays() {
        let mut c = RayCache::new(4, entry_bytes(4) * 2);
        assert!(c.store(key(0, 1), &[1.0; 4], || vec![Vec4::ONE; 4]));
        assert!(c.store(key(1, 1), &[0.5; 4], || vec![Vec4::ONE; 4]));
        assert!(
            !c.store(key(2, 1), &[0.5; 4], || vec![Vec4::ONE; 4]),
            "full"
        );
        assert!(
            c.store(key(0, 1), &[0.25; 4], || vec![Vec4::ONE; 4]),
            "an update fits"
        );
        assert_eq!(c.get(key(0, 1)).unwrap().scores[..], [0.25; 4]);
        let mut m = RayMask::none(4);
        m.set(2);
        assert!(c.mark_stale(key(1, 1), &m));
        assert!(!c.mark_stale(key(2, 1), &m));
        assert!(c.get(key(1, 1)).unwrap().stale.has(2));
        c.store(key(1, 1), &[0.5; 4], || vec![Vec4::ONE; 4]);
        assert!(c.get(key(1, 1)).unwrap().stale.is_empty(), "traced again");
        c.forget(key(1, 1));
        assert_eq!(c.len(), 1);
        assert!(c.get(key(1, 1)).is_none());
        // Its place goes to the next point.
        assert!(c.store(key(4, 9), &[0.75; 4], || vec![Vec4::ZERO; 4]));
        assert_eq!(c.get(key(4, 9)).unwrap().scores[..], [0.75; 4]);
        assert_eq!(c.get(key(4, 9)).unwrap().rays[..], [Vec4::ZERO; 4]);
        assert!(c.get(key(4, 9)).unwrap().stale.is_empty());
        assert_eq!(c.get(key(0, 1)).unwrap().scores[..], [0.25; 4]);
        c.forget(key(4, 9));
        assert!(
            !c.store(key(0, 2), &[0.5; 3], || vec![Vec4::ONE; 3]),
            "wrong ray count"
        );
    }

    #[test]
    fn the_default_cap_holds_about_94000_points_of_32_rays() {
        // The figure `PipelineConfig::ray_cache_bytes` states.
        let c = RayCache::new(32, 64 << 20);
        assert_eq!(entry_bytes(32), 712);
        assert_eq!(c.max_entries, 94_254);
    }
}
