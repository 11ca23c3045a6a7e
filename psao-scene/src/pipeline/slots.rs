//! A `u32` per point, by (instance, point) key
//! ([`key`](super::ray_cache::key)), in one dense array per instance: the
//! per-point state a step reads for tens of thousands of points in point
//! order (what waits, what has kept scores, what reaches the envelope).
//! A hash map there costs a cache miss a point; these reads run along
//! memory.

/// A `u32` per point, 0 for a point never set.
#[derive(Clone, Debug, Default)]
pub struct PointSlots {
    instances: Vec<Vec<u32>>,
}

impl PointSlots {
    /// The value of point `key` (0 if never set).
    pub fn get(&self, key: u64) -> u32 {
        let (i, k) = ((key >> 32) as usize, key as u32 as usize);
        self.instances
            .get(i)
            .and_then(|v| v.get(k))
            .copied()
            .unwrap_or(0)
    }

    /// Sets point `key`'s value (the instance's array grows to hold it).
    pub fn set(&mut self, key: u64, value: u32) {
        let (i, k) = ((key >> 32) as usize, key as u32 as usize);
        if i >= self.instances.len() {
            if value == 0 {
                return;
            }
            self.instances.resize_with(i + 1, Vec::new);
        }
        let v = &mut self.instances[i];
        if k >= v.len() {
            if value == 0 {
                return;
            }
            v.resize(k + 1, 0);
        }
        v[k] = value;
    }

    /// Sets instance `i`'s values back to 0, its memory given back.
    pub fn drop_instance(&mut self, i: usize) {
        if let Some(v) = self.instances.get_mut(i) {
            *v = Vec::new();
        }
    }

    /// Sets every value back to 0 (keeping the memory).
    pub fn clear(&mut self) {
        for v in &mut self.instances {
            v.clear();
        }
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.instances
            .iter()
            .map(|v| v.capacity() as u64 * 4 + 24)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::ray_cache::key;

    #[test]
    fn values_are_kept_per_point_and_zero_elsewhere() {
        let mut s = PointSlots::default();
        assert_eq!(s.get(key(3, 7)), 0);
        s.set(key(3, 7), 5);
        s.set(key(0, 0), 1);
        s.set(key(9, 1 << 20), 0); // 0 far away: nothing grows
        assert_eq!(s.get(key(3, 7)), 5);
        assert_eq!(s.get(key(3, 6)), 0);
        assert_eq!(s.get(key(0, 0)), 1);
        assert_eq!(s.get(key(9, 1 << 20)), 0);
        assert!(s.memory_bytes() < 1024);
        s.clear();
        assert_eq!(s.get(key(3, 7)), 0);
        s.set(key(3, 2), 4);
        assert_eq!(s.get(key(3, 2)), 4);
        assert_eq!(s.get(key(3, 7)), 0, "cleared values stay 0");
        s.set(key(0, 0), 2);
        let held = s.memory_bytes();
        s.drop_instance(3);
        assert!(s.memory_bytes() < held, "its memory is given back");
        let dropped = s.memory_bytes();
        s.drop_instance(40);
        assert_eq!(s.memory_bytes(), dropped, "no such instance: nothing");
        assert_eq!(s.get(key(3, 2)), 0, "a dropped instance's values are 0");
        assert_eq!(s.get(key(0, 0)), 2, "the others' stay");
        s.set(key(3, 2), 6);
        assert_eq!(s.get(key(3, 2)), 6, "it grows back");
    }
}
