//! CPU reconstruction of AO at a surface point from a mirror (paper eq. 2-4),
//! in instance-local space.

use glam::{Affine3A, IVec3, Vec3};

use crate::client::mirror::InstanceMirror;
use crate::grid::InstanceDef;
use crate::wire::point::{PointWord, normal_table};

/// Parameters of eq. 2-3 for one instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightParams {
    /// Interpolation radius r.
    pub radius: f32,
    /// Normal threshold T_n.
    pub t_n: f32,
    /// Direction threshold T_d.
    pub t_d: f32,
    /// Distance below which the direction test is skipped: the largest
    /// position quantization offset, `|cell_size| / 64`. Closer than that,
    /// the direction from `x` to a point is quantization noise, and eq. 3
    /// would reject a point's own sample whenever that noise happens to lie
    /// along the normal.
    pub noise: f32,
}

impl WeightParams {
    /// The parameters of an instance definition.
    pub fn of(def: &InstanceDef) -> WeightParams {
        WeightParams {
            radius: def.radius,
            t_n: def.t_n,
            t_d: def.t_d,
            noise: def.cell_size.length() / 64.0,
        }
    }
}

/// The weight of eq. 2 with the rejections of eq. 3, for a point at `p`
/// with normal `n_p` seen from surface point `x` with normal `n_x`.
#[inline]
pub fn weight(p: Vec3, n_p: Vec3, x: Vec3, n_x: Vec3, w: &WeightParams) -> f32 {
    let (r, t_n, t_d) = (w.radius, w.t_n, w.t_d);
    let d = p - x;
    let dist2 = d.length_squared();
    // Clearly beyond r: out before the square root. The margin covers the
    // rounding of the square and the root; the exact test is below. (NaN
    // fails every test and gives weight 0.)
    if dist2.is_nan() || dist2 > r * r * (1.0 + 1e-4) {
        return 0.0;
    }
    let facing = n_p.dot(n_x);
    if facing.is_nan() || facing <= t_n {
        return 0.0;
    }
    let dist = dist2.sqrt();
    let a = (r - dist) / r;
    if a.is_nan() || a <= 0.0 {
        return 0.0;
    }
    if dist > w.noise {
        let c = n_p.dot(d) / dist;
        if c * c >= t_d {
            return 0.0;
        }
    }
    a
}

/// The first of the 2x2x2 cells around a local position: the cell whose
/// centre is the nearest at or below `x` on every axis.
pub fn base_cell(inst: &InstanceMirror, x: Vec3) -> IVec3 {
    let d = inst.def();
    let g = (x - d.origin) / d.cell_size - 0.5;
    let g = g.clamp(Vec3::splat(-2.0), d.dims.as_vec3() + 1.0);
    g.floor().as_ivec3()
}

/// AO at instance-local position `x` with unit local normal `n` (eq. 4):
/// the weighted mean of the points in the 2x2x2 cells around `x`. When
/// every weight is zero, the same cells are weighed again with twice the
/// radius (spec/wire-format.md 7.3); when those are zero too, or `x` or `n`
/// is not finite, the result is 1 (open).
pub fn reconstruct_ao(inst: &InstanceMirror, x: Vec3, n: Vec3) -> f32 {
    reconstruct_ao_keeping(inst, x, n, |_, _, _| true)
}

/// [`reconstruct_ao`] with a filter on the candidates: a point that passes
/// eq. 2-3 with a weight above 0 counts only when
/// `keep(word, position, normal)` is true, in both passes (`word`: the
/// point's index in [`InstanceMirror::words`]; position and normal in
/// local space). With a filter that keeps every point this is
/// [`reconstruct_ao`], bit for bit. The optional test of
/// spec/wire-format.md 7.3.1 is such a filter
/// ([`reconstruct_ao_seen`](crate::reconstruct_ao_seen)).
pub fn reconstruct_ao_keeping(
    inst: &InstanceMirror,
    x: Vec3,
    n: Vec3,
    mut keep: impl FnMut(usize, Vec3, Vec3) -> bool,
) -> f32 {
    let d = *inst.def();
    if !x.is_finite() || !n.is_finite() {
        return 1.0;
    }
    let params = WeightParams::of(&d);
    let (sum_w, sum) = weighted_sum(inst, x, n, &params, &mut keep);
    if sum_w > 0.0 {
        return sum / sum_w;
    }
    // No point within r (a gap in the points' spread, or points dropped
    // from a full cell): look once more with twice the radius, over the
    // same cells. (One sweep for both radii was measured slower: most
    // pixels are done at r, and the shell out to 2r holds seven times the
    // points.)
    let wide = WeightParams {
        radius: 2.0 * params.radius,
        ..params
    };
    let (sum_w, sum) = weighted_sum(inst, x, n, &wide, &mut keep);
    if sum_w > 0.0 { sum / sum_w } else { 1.0 }
}

/// The weight sum and the weighted AO sum of eq. 4 over the 2x2x2 cells
/// around `x`, over the points `keep` keeps among those of weight above 0.
fn weighted_sum(
    inst: &InstanceMirror,
    x: Vec3,
    n: Vec3,
    params: &WeightParams,
    keep: &mut impl FnMut(usize, Vec3, Vec3) -> bool,
) -> (f32, f32) {
    let (mut sum_w, mut sum) = (0.0f32, 0.0f32);
    for_each_indexed_candidate(inst, x, |word, p, n_p, ao| {
        let a = weight(p, n_p, x, n, params);
        if a > 0.0 && !keep(word, p, n_p) {
            return;
        }
        sum_w += a;
        sum += a * ao;
    });
    (sum_w, sum)
}

/// Calls `f(position, normal, ao)` for every point eq. 4 weighs at
/// instance-local `x`: the points of the 2x2x2 cells around it, each
/// cell's whole overflow chain included, in local space.
pub fn for_each_candidate(inst: &InstanceMirror, x: Vec3, mut f: impl FnMut(Vec3, Vec3, f32)) {
    for_each_indexed_candidate(inst, x, |_, p, n_p, ao| f(p, n_p, ao));
}

/// [`for_each_candidate`] with each point's index in
/// [`InstanceMirror::words`] first.
fn for_each_indexed_candidate(
    inst: &InstanceMirror,
    x: Vec3,
    mut f: impl FnMut(usize, Vec3, Vec3, f32),
) {
    let d = *inst.def();
    let cap = d.cell_capacity as usize;
    let normals = normal_table();
    let base = base_cell(inst, x);
    let dims = d.dims.as_ivec3();
    // The eight cells' first pool cells first, then each one's first
    // word, then the points: the hash buckets' and the cells' loads do not
    // wait on each other or on the points' arithmetic (they miss the cache
    // more than anything else in the reconstruction). Cell `i` of the
    // 2x2x2 is `base + (i & 1, i >> 1 & 1, i >> 2)`.
    let cell = |i: usize| base + IVec3::new(i as i32 & 1, i as i32 >> 1 & 1, i as i32 >> 2);
    let inside = |c: IVec3| !(c.cmplt(IVec3::ZERO).any() || c.cmpge(dims).any());
    let mut heads = [None; 8];
    for (i, head) in heads.iter_mut().enumerate() {
        let c = cell(i);
        if inside(c) {
            *head = inst.chain_head(d.key(c.as_uvec3()));
        }
    }
    // An empty cell is skipped.
    let words = inst.words();
    for head in &mut heads {
        *head = head.filter(|&h| {
            words
                .get(h as usize * cap)
                .is_some_and(|&w| PointWord(w).is_allocated())
        });
    }
    for (i, &head) in heads.iter().enumerate() {
        let Some(head) = head else { continue };
        let c = cell(i).as_uvec3();
        let min = d.cell_min(c);
        for cell in inst.chain_from(d.key(c), head) {
            for (slot, w) in inst.cell_points(cell).enumerate() {
                let p = min + w.frac() * d.cell_size;
                let word = cell as usize * cap + slot;
                f(word, p, normals[w.fields().normal as usize], w.ao());
            }
        }
    }
}

/// Maps a world position and unit normal into instance-local space with the
/// inverse of a local-to-world transform (normals by the transpose of the
/// linear part, renormalized). Returns `None` for a singular or
/// non-finite transform, or when the result is not finite. For many points
/// of one instance, make a [`LocalFrame`] once (the same arithmetic, the
/// inverse computed once).
pub fn world_to_local(local_to_world: &Affine3A, pos: Vec3, normal: Vec3) -> Option<(Vec3, Vec3)> {
    LocalFrame::new(local_to_world)?.map(pos, normal)
}

/// The world-to-local mapping of one transform, for mapping many points:
/// [`world_to_local`] with its inverse computed once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    to_local: Affine3A,
    normal: glam::Mat3A,
}

impl LocalFrame {
    /// The frame of a local-to-world transform; `None` when it is singular
    /// (`|det| <= f32::MIN_POSITIVE`) or not finite.
    pub fn new(local_to_world: &Affine3A) -> Option<LocalFrame> {
        let det = local_to_world.matrix3.determinant();
        if !det.is_finite() || det.abs() <= f32::MIN_POSITIVE {
            return None;
        }
        Some(LocalFrame {
            to_local: local_to_world.inverse(),
            normal: local_to_world.matrix3.transpose(),
        })
    }

    /// A world position and unit normal in local space; `None` when the
    /// result is not finite.
    pub fn map(&self, pos: Vec3, normal: Vec3) -> Option<(Vec3, Vec3)> {
        let x = self.to_local.transform_point3(pos);
        let n = self.normal.mul_vec3(normal).normalize_or_zero();
        (x.is_finite() && n.is_finite()).then_some((x, n))
    }
}
