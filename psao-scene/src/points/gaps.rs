//! Gap filling after sample elimination: a spawned point with no kept point
//! facing its way within the interpolation radius is kept too.
//!
//! Elimination keeps about half of the spawned points in every region, so
//! a strip narrower than the point spacing (a groove between panels, a
//! rim, a thin bar) keeps its share of the *area* and ends up with points
//! farther apart than the radius: a client pixel there finds no point that
//! faces its way within reach and is left open. Filling keeps, for every
//! spawned point, a kept point within `reach` that faces the same side
//! (normals at less than 90 degrees, as elimination's neighbours), so the
//! surface is covered wherever it was spawned on.

use glam::{IVec3, Vec3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::generate::{Anchor, point_on};
use crate::model::mesh::Mesh;
use crate::random::uniform;

/// Most fill candidates on one triangle.
const MAX_CANDIDATES_PER_TRIANGLE: usize = 64;

/// Fill candidates on `mesh`: each triangle's centroid (but on triangles
/// of zero area), and more random
/// spots on it, one per half `reach` of its longest edge (at most
/// [`MAX_CANDIDATES_PER_TRIANGLE`]), so that every strip has candidates
/// along its length, however little area it has; none in alpha-mask
/// holes. Deterministic for a seed; in triangle order.
pub fn candidates(mesh: &Mesh, reach: f32, seed: u64) -> (Vec<Vec3>, Vec<Vec3>, Vec<Anchor>) {
    let seed = seed ^ 0x6761_7073; // "gaps"
    let per: Vec<Vec<(Vec3, Vec3, Anchor)>> = (0..mesh.triangle_count())
        .into_par_iter()
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            let area = (b - a).cross(c - a).length();
            if !(area.is_finite() && area > 0.0) {
                // Zero-area (or non-finite) triangles get no point, as
                // spawning draws none on them.
                return Vec::new();
            }
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            let more = if reach > 0.0 && longest.is_finite() {
                ((2.0 * longest / reach).ceil() as usize).min(MAX_CANDIDATES_PER_TRIANGLE)
            } else {
                0
            };
            let third = 1.0 / 3.0;
            std::iter::once([third; 3])
                .chain((0..more as u32).map(|j| {
                    let k = (t as u32).wrapping_mul(MAX_CANDIDATES_PER_TRIANGLE as u32) + j;
                    let (r1, r2) = (uniform(seed, 1, k).sqrt(), uniform(seed, 2, k));
                    [1.0 - r1, r1 * (1.0 - r2), r1 * r2]
                }))
                .filter_map(|w| point_on(mesh, t, w))
                .collect()
        })
        .collect();
    let n: usize = per.iter().map(Vec::len).sum();
    let (mut pos, mut nrm, mut anchors) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for (p, q, a) in per.into_iter().flatten() {
        pos.push(p);
        nrm.push(q);
        anchors.push(a);
    }
    (pos, nrm, anchors)
}

/// Adds to `kept` (ascending indices into `points`) each point of `points`
/// that has no kept point facing its way (`normals` at a positive dot
/// product) closer than `reach`, in index order, each one added counting
/// for those after it. Returns the new kept list, ascending.
pub fn fill_gaps(points: &[Vec3], normals: &[Vec3], kept: Vec<usize>, reach: f32) -> Vec<usize> {
    if !(reach.is_finite() && reach > 0.0) || kept.is_empty() {
        return kept;
    }
    let cell = |p: Vec3| (p / reach).floor().as_ivec3();
    let mut grid: FxHashMap<IVec3, Vec<u32>> = FxHashMap::default();
    for &i in &kept {
        grid.entry(cell(points[i])).or_default().push(i as u32);
    }
    let covered = |grid: &FxHashMap<IVec3, Vec<u32>>, i: usize| {
        let (p, n, c) = (points[i], normals[i], cell(points[i]));
        (-1..=1).any(|dz| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    grid.get(&(c + IVec3::new(dx, dy, dz))).is_some_and(|list| {
                        list.iter().any(|&j| {
                            let j = j as usize;
                            points[j].distance(p) < reach && normals[j].dot(n) > 0.0
                        })
                    })
                })
            })
        })
    };
    let mut is_kept = vec![false; points.len()];
    for &i in &kept {
        is_kept[i] = true;
    }
    // Most points are covered by the kept ones: find the rest in parallel,
    // then add them one by one (each may cover later ones).
    let open: Vec<usize> = (0..points.len())
        .into_par_iter()
        .filter(|&i| !is_kept[i] && points[i].is_finite() && !covered(&grid, i))
        .collect();
    if open.is_empty() {
        return kept;
    }
    let mut out = kept;
    for i in open {
        if !covered(&grid, i) {
            grid.entry(cell(points[i])).or_default().push(i as u32);
            out.push(i);
        }
    }
    out.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_strip_keeps_a_point_within_reach_of_every_spawned_one() {
        // Points every 0.1 along a line, one kept at the start.
        let points: Vec<Vec3> = (0..20).map(|i| Vec3::X * (i as f32 * 0.1)).collect();
        let normals = vec![Vec3::Y; points.len()];
        let kept = fill_gaps(&points, &normals, vec![0], 0.25);
        for (i, p) in points.iter().enumerate() {
            assert!(
                kept.iter().any(|&j| points[j].distance(*p) < 0.25),
                "point {i} is {p}, kept {kept:?}"
            );
        }
        // Every third point is enough, and only that is added.
        assert_eq!(kept, vec![0, 3, 6, 9, 12, 15, 18]);
        assert!(kept.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn points_facing_away_do_not_cover() {
        let points = vec![Vec3::ZERO, Vec3::X * 0.01];
        let normals = vec![Vec3::Y, -Vec3::Y];
        assert_eq!(fill_gaps(&points, &normals, vec![0], 1.0), vec![0, 1]);
        // The same side covers.
        let normals = vec![Vec3::Y, Vec3::Y];
        assert_eq!(fill_gaps(&points, &normals, vec![0], 1.0), vec![0]);
    }

    #[test]
    fn nothing_kept_or_no_reach_changes_nothing() {
        let points = vec![Vec3::ZERO, Vec3::X];
        let normals = vec![Vec3::Y; 2];
        assert!(fill_gaps(&points, &normals, Vec::new(), 1.0).is_empty());
        assert_eq!(fill_gaps(&points, &normals, vec![1], f32::NAN), vec![1]);
        assert_eq!(fill_gaps(&points, &normals, vec![1], 0.0), vec![1]);
    }
}
