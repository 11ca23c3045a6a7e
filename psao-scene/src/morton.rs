//! Morton (Z-order) sorting of points: nearby points end up near each
//! other in memory, for coherent rays and compact tiles.

use glam::Vec3;
use rayon::prelude::*;

/// Indices of `points` sorted along a 30-bit Morton curve over their bounds.
pub fn morton_order(points: &[Vec3]) -> Vec<usize> {
    let Some(&first) = points.first() else {
        return Vec::new();
    };
    let (lo, hi) = points
        .iter()
        .filter(|p| p.is_finite())
        .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    let scale = 1023.0 / (hi - lo).max_element().max(f32::MIN_POSITIVE);
    let spread = |v: u32| {
        let mut x = v & 0x3FF;
        x = (x | (x << 16)) & 0x030000FF;
        x = (x | (x << 8)) & 0x0300F00F;
        x = (x | (x << 4)) & 0x030C30C3;
        (x | (x << 2)) & 0x09249249
    };
    let code = |p: Vec3| {
        let q = ((p - lo) * scale).clamp(Vec3::ZERO, Vec3::splat(1023.0));
        spread(q.x as u32) | (spread(q.y as u32) << 1) | (spread(q.z as u32) << 2)
    };
    // Keys are unique (the index breaks ties): the parallel sort gives
    // the one order whatever the thread count.
    let mut keyed: Vec<(u32, usize)> = (0..points.len())
        .into_par_iter()
        .map(|i| (code(points[i]), i))
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}
