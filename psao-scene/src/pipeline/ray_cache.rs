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
//! reached meanwhile (`stale`); a point put aside by culling loses them.

use glam::Vec4;
use rustc_hash::FxHashMap;

use super::reach::RayMask;

/// One point's kept scores.
#[derive(Clone, Debug)]
pub struct Entry {
    /// Each ray's score as last traced (or, for the rays in `stale`, as
    /// traced before motion reached them).
    pub scores: Box<[f32]>,
    /// Rays motion reached since they were traced.
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
    entries: FxHashMap<u64, Entry>,
}

/// Bytes one entry of `rays` rays takes, with the map's share.
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
            max_entries: (max_bytes / entry_bytes(rays)) as usize,
            entries: FxHashMap::default(),
        }
    }

    /// A point's entry.
    pub fn get(&self, key: u64) -> Option<&Entry> {
        self.entries.get(&key)
    }

    /// Whether a new point would be stored (the cache is not full).
    pub fn has_room(&self) -> bool {
        self.entries.len() < self.max_entries
    }

    /// Stores a point's fresh scores (its stale rays cleared), with its
    /// rays (`rays()` is called only for a point not held yet). A new point
    /// is not stored once the cache is full; returns whether it is held.
    pub fn store(&mut self, key: u64, scores: &[f32], rays: impl FnOnce() -> Vec<Vec4>) -> bool {
        if let Some(e) = self.entries.get_mut(&key) {
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
        self.entries.insert(
            key,
            Entry {
                scores: scores.into(),
                stale: RayMask::none(self.rays),
                rays: rays.into(),
            },
        );
        true
    }

    /// Marks rays of a waiting point as reached by motion. Returns whether
    /// the point has an entry.
    pub fn mark_stale(&mut self, key: u64, reached: &RayMask) -> bool {
        match self.entries.get_mut(&key) {
            Some(e) => {
                e.stale.union(reached);
                true
            }
            None => false,
        }
    }

    /// Forgets a point's scores (it will be traced in full).
    pub fn forget(&mut self, key: u64) {
        self.entries.remove(&key);
    }

    /// Points held.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.entries.capacity() as u64 * entry_bytes(self.rays)
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
        assert!(
            !c.store(key(0, 2), &[0.5; 3], || vec![Vec4::ONE; 3]),
            "wrong ray count"
        );
    }
}
