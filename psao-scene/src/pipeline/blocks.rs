//! Blocks of a rigid instance's points, for choosing the points within
//! reach of motion without testing each ([`PointBlocks`]).

use glam::{Affine3A, Vec3};
use rayon::prelude::*;

use crate::model::mesh::transformed_bounds;
use crate::morton::morton_order;

/// Points per block.
const BLOCK: usize = 64;

/// Fewest blocks [`PointBlocks::within`] tests in parallel.
const PARALLEL_BLOCKS: usize = 256;

/// A rigid instance's points in blocks of [`BLOCK`] along a Morton curve,
/// each with its local bounds: a step tests a block's box against what
/// motion swept, and only the points of the blocks it meets one by one.
#[derive(Clone, Debug, Default)]
pub(super) struct PointBlocks {
    /// Point indices, block by block.
    order: Vec<u32>,
    /// Each block's local bounds.
    boxes: Vec<(Vec3, Vec3)>,
}

/// Whether two boxes (min, max) overlap (touching counts).
pub(super) fn overlaps(a: (Vec3, Vec3), b: (Vec3, Vec3)) -> bool {
    a.0.cmple(b.1).all() && b.0.cmple(a.1).all()
}

/// Whether `p` lies inside any of the boxes (min, max), borders included.
pub(super) fn inside_any(p: Vec3, boxes: &[(Vec3, Vec3)]) -> bool {
    boxes
        .iter()
        .any(|b| p.cmpge(b.0).all() && p.cmple(b.1).all())
}

impl PointBlocks {
    /// The blocks of the points at `positions` (local space).
    pub fn new(positions: &[Vec3]) -> PointBlocks {
        let order: Vec<u32> = morton_order(positions)
            .into_iter()
            .map(|i| i as u32)
            .collect();
        let boxes = order
            .chunks(BLOCK)
            .map(|c| {
                let first = positions[c[0] as usize];
                c.iter().fold((first, first), |(lo, hi), &k| {
                    let p = positions[k as usize];
                    (lo.min(p), hi.max(p))
                })
            })
            .collect();
        PointBlocks { order, boxes }
    }

    /// Whether it holds the blocks of `points` points.
    pub fn covers(&self, points: usize) -> bool {
        self.order.len() == points
    }

    /// The points at `positions` (local; those the blocks were made of)
    /// that `transform` places inside any of the world boxes `swept`,
    /// ascending: the same as testing every point.
    pub fn within(
        &self,
        positions: &[Vec3],
        transform: &Affine3A,
        swept: &[(Vec3, Vec3)],
    ) -> Vec<u32> {
        // One block's points inside the boxes, each tested only against
        // the boxes its block's box meets (none where it meets none: a
        // floor under many moving parts meets a few of them a block).
        let block = |(chunk, &b): (&[u32], &(Vec3, Vec3))| -> Vec<u32> {
            let world = transformed_bounds(transform, b);
            let near: Vec<(Vec3, Vec3)> = swept
                .iter()
                .copied()
                .filter(|&s| overlaps(s, world))
                .collect();
            if near.is_empty() {
                return Vec::new();
            }
            chunk
                .iter()
                .copied()
                .filter(|&k| inside_any(transform.transform_point3(positions[k as usize]), &near))
                .collect()
        };
        // Many blocks are tested in parallel (a floor under many moving
        // parts); the points are the same either way, sorted.
        let mut out: Vec<u32> = if self.boxes.len() >= PARALLEL_BLOCKS {
            self.order
                .par_chunks(BLOCK)
                .zip(self.boxes.par_iter())
                .flat_map_iter(block)
                .collect()
        } else {
            self.order
                .chunks(BLOCK)
                .zip(&self.boxes)
                .flat_map(block)
                .collect()
        };
        out.sort_unstable();
        out
    }

    /// Bytes held (capacity).
    pub fn memory_bytes(&self) -> u64 {
        self.order.capacity() as u64 * 4 + self.boxes.capacity() as u64 * 24
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_choose_the_points_each_test_would() {
        // Few blocks (tested in turn) and many (in parallel).
        for n in [1_000u32, (PARALLEL_BLOCKS * BLOCK) as u32 + 777] {
            let positions: Vec<Vec3> = (0..n)
                .map(|k| {
                    let u = |s| crate::random::uniform(s, k, 0) * 10.0;
                    Vec3::new(u(1), u(2) * 0.1, u(3))
                })
                .collect();
            let blocks = PointBlocks::new(&positions);
            assert!(blocks.covers(n as usize));
            let t = Affine3A::from_rotation_y(0.3)
                * Affine3A::from_translation(Vec3::new(1.0, 0.0, -2.0));
            let swept = [
                (Vec3::new(2.0, -1.0, 1.0), Vec3::new(4.0, 1.0, 3.0)),
                (Vec3::new(-5.0, -1.0, -5.0), Vec3::new(-4.0, 1.0, -4.5)),
            ];
            let each: Vec<u32> = (0..n)
                .filter(|&k| {
                    let p = t.transform_point3(positions[k as usize]);
                    swept
                        .iter()
                        .any(|b| p.cmpge(b.0).all() && p.cmple(b.1).all())
                })
                .collect();
            assert!(!each.is_empty());
            assert_eq!(blocks.within(&positions, &t, &swept), each, "{n} points");
            assert!(blocks.within(&positions, &t, &[]).is_empty());
        }
    }
}
