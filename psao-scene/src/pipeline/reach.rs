//! Which rays of a static point a step's motion can reach: a ray whose
//! segment enters none of the boxes the moving instances occupied before
//! and after the step hits what it hit before, so its score is unchanged,
//! bit for bit (the same ray against the same static triangles). A point
//! none of whose rays can be reached keeps its AO without a trace; one
//! with some re-traces only those when its other rays' scores are kept
//! ([`super::ray_cache`]).

use std::borrow::Cow;
use std::sync::OnceLock;

use glam::{IVec3, Vec3, Vec3A, Vec4};
use rustc_hash::FxHashMap;

use crate::model::mesh::box_corners;
use crate::trace::ao::{Estimator, PointRays};
use crate::trace::geometry::RAY_LEAD;

/// A set of rays of one point, one bit per ray: the first 64 in a word
/// held inline (a point's rays are most often no more), the rest on the
/// heap.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RayMask {
    rays: u32,
    first: u64,
    rest: Vec<u64>,
}

impl RayMask {
    /// No ray of `rays`.
    pub fn none(rays: u32) -> RayMask {
        RayMask {
            rays,
            first: 0,
            rest: vec![0; (rays as usize).div_ceil(64).saturating_sub(1)],
        }
    }

    /// Every ray of `rays`.
    pub fn all(rays: u32) -> RayMask {
        let mut m = RayMask::none(rays);
        for k in 0..rays {
            m.set(k);
        }
        m
    }

    /// The word holding ray `k`'s bit.
    fn word(&self, k: u32) -> Option<&u64> {
        match k / 64 {
            0 => Some(&self.first),
            w => self.rest.get(w as usize - 1),
        }
    }

    /// The word holding ray `k`'s bit, to change.
    fn word_mut(&mut self, k: u32) -> Option<&mut u64> {
        match k / 64 {
            0 => Some(&mut self.first),
            w => self.rest.get_mut(w as usize - 1),
        }
    }

    /// Adds ray `k` (of those the mask was made for; others are ignored).
    pub fn set(&mut self, k: u32) {
        if k >= self.rays {
            return;
        }
        if let Some(w) = self.word_mut(k) {
            *w |= 1 << (k % 64);
        }
    }

    /// Whether ray `k` is in the set.
    pub fn has(&self, k: u32) -> bool {
        self.word(k).is_some_and(|w| w & (1 << (k % 64)) != 0)
    }

    /// Adds every ray of `other`.
    pub fn union(&mut self, other: &RayMask) {
        if self.rest.len() < other.rest.len() {
            self.rest.resize(other.rest.len(), 0);
        }
        self.rays = self.rays.max(other.rays);
        self.first |= other.first;
        for (a, b) in self.rest.iter_mut().zip(&other.rest) {
            *a |= b;
        }
    }

    /// Its words, the first ray's first.
    fn words(&self) -> impl Iterator<Item = u64> + '_ {
        std::iter::once(self.first).chain(self.rest.iter().copied())
    }

    /// Rays in the set.
    pub fn count(&self) -> u32 {
        self.words().map(|w| w.count_ones()).sum()
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.words().all(|w| w == 0)
    }

    /// The rays in the set, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.words().enumerate().flat_map(|(w, bits)| {
            let mut bits = bits;
            std::iter::from_fn(move || {
                if bits == 0 {
                    return None;
                }
                let b = bits.trailing_zeros();
                bits &= bits - 1;
                Some(w as u32 * 64 + b)
            })
        })
    }

    /// Bytes its words take on the heap.
    pub fn heap_bytes(&self) -> u64 {
        self.rest.capacity() as u64 * 8
    }
}

/// The world boxes a step's motion occupied: per moving or deforming
/// instance, its bounds before and after the step together, padded
/// against rounding in the ray-box test.
#[derive(Clone, Debug, Default)]
pub struct MotionBoxes {
    boxes: Vec<(Vec3A, Vec3A)>,
    /// With many boxes, which lie near each place: made on the first
    /// look from a point ([`Self::seen_from`]).
    index: OnceLock<BoxIndex>,
}

/// Boxes fewer than this are looked at one by one from every point.
const INDEX_FROM: usize = 32;

/// A box that would cover more cells of a [`BoxIndex`] than this is
/// looked at from every point instead.
const INDEX_MOST_CELLS: f64 = 512.0;

/// Which boxes of a [`MotionBoxes`] lie within `len` of each place: a
/// grid of cubes of side twice `len`, each listing (ascending) the boxes
/// that, grown by `len` and a margin above rounding, meet it; and the
/// boxes too large to list, looked at from everywhere.
#[derive(Clone, Debug)]
struct BoxIndex {
    /// The reach it was made for.
    len: f32,
    /// The cubes' side.
    cell: f32,
    /// Per cube, the boxes near it.
    cells: FxHashMap<IVec3, Vec<u32>>,
    /// The boxes listed in no cube.
    everywhere: Vec<u32>,
}

impl BoxIndex {
    fn new(boxes: &[(Vec3A, Vec3A)], len: f32) -> BoxIndex {
        let cell = (2.0 * len).max(1e-3);
        let mut cells: FxHashMap<IVec3, Vec<u32>> = FxHashMap::default();
        let mut everywhere = Vec::new();
        let at = |p: Vec3A| (p / cell).floor();
        for (i, &(lo, hi)) in boxes.iter().enumerate() {
            // Grown by more than any box the look keeps lies from a point
            // it keeps it for (`seen_from`'s reach and margin).
            let far = lo.abs().max(hi.abs()).max_element();
            let grow = Vec3A::splat(len * 1.01 + far * (1.0 / (1u32 << 15) as f32) + 1e-6);
            let (a, b) = (at(lo - grow), at(hi + grow));
            let n = (b - a + Vec3A::ONE).max(Vec3A::ZERO);
            // (In f64: a box of a file's wild transform spans up to 2^31
            // cubes a side, past i64 when multiplied.)
            let count = f64::from(n.x) * f64::from(n.y) * f64::from(n.z);
            // (A box past the grid's range of cubes, or not finite, too.)
            let on_grid = |c: Vec3A| c.is_finite() && c.abs().max_element() < (i32::MAX / 2) as f32;
            if !on_grid(a) || !on_grid(b) || !(1.0..=INDEX_MOST_CELLS).contains(&count) {
                everywhere.push(i as u32);
                continue;
            }
            let (a, b) = (a.as_ivec3(), b.as_ivec3());
            for z in a.z..=b.z {
                for y in a.y..=b.y {
                    for x in a.x..=b.x {
                        cells.entry(IVec3::new(x, y, z)).or_default().push(i as u32);
                    }
                }
            }
        }
        BoxIndex {
            len,
            cell,
            cells,
            everywhere,
        }
    }

    /// The boxes that may lie within the reach of `origin`, ascending
    /// (`None` for an origin off the grid: every box); borrowed from its
    /// cube where no box is listed everywhere.
    fn near(&self, origin: Vec3A) -> Option<Cow<'_, [u32]>> {
        let key = (origin / self.cell).floor();
        if !key.is_finite() || key.abs().max_element() >= i32::MAX as f32 {
            return None;
        }
        let listed: &[u32] = self
            .cells
            .get(&key.as_ivec3())
            .map_or(&[], |v| v.as_slice());
        if self.everywhere.is_empty() {
            return Some(Cow::Borrowed(listed));
        }
        let mut out = Vec::with_capacity(listed.len() + self.everywhere.len());
        out.extend_from_slice(listed);
        out.extend_from_slice(&self.everywhere);
        out.sort_unstable();
        Some(Cow::Owned(out))
    }
}

impl MotionBoxes {
    /// The boxes, each padded by `pad` plus a part that grows with its
    /// coordinates (so that rounding in the slab test never misses a
    /// triangle the tracer would hit).
    pub fn new(boxes: impl IntoIterator<Item = (Vec3, Vec3)>, pad: f32) -> MotionBoxes {
        MotionBoxes {
            index: OnceLock::new(),
            boxes: boxes
                .into_iter()
                .map(|(lo, hi)| {
                    let far = lo.abs().max(hi.abs()).max_element();
                    let p = Vec3::splat(pad + far * (1.0 / (1u32 << 18) as f32));
                    (Vec3A::from(lo - p), Vec3A::from(hi + p))
                })
                .collect(),
        }
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }

    /// Bytes its boxes take on the heap.
    pub fn heap_bytes(&self) -> u64 {
        (self.boxes.capacity() * std::mem::size_of::<(Vec3A, Vec3A)>()) as u64
    }

    /// Boxes that hold every box of `sets` (each padded as it was): a box
    /// that meets one already taken is merged with it, into the box that
    /// holds both. A ray that reaches a box of some set reaches one of
    /// these; one of these may reach a little more (where a part turned,
    /// the corners between its boxes), never less. A part that moves a
    /// little each step leaves one box over its path.
    pub fn joined<'a>(sets: impl IntoIterator<Item = &'a MotionBoxes>) -> MotionBoxes {
        let mut boxes: Vec<(Vec3A, Vec3A)> = Vec::new();
        for &(lo, hi) in sets.into_iter().flat_map(|m| m.boxes.iter()) {
            match boxes
                .iter_mut()
                .find(|(l, h)| lo.cmple(*h).all() && l.cmple(hi).all())
            {
                Some((l, h)) => {
                    *l = l.min(lo);
                    *h = h.max(hi);
                }
                None => boxes.push((lo, hi)),
            }
        }
        MotionBoxes {
            boxes,
            index: OnceLock::new(),
        }
    }

    /// The boxes a point's hemisphere of rays can enter, as it sees
    /// them: those within `len` of its rays' origin with a corner on the
    /// side its normal faces, each with the cone of directions that can
    /// enter it and the run of its rays that can point into that cone. A
    /// point whose hemisphere reaches none needs no ray tested (the reach
    /// of item 3 of issue 20: not only the sphere around it); one that
    /// sees a box tests only the rays that can point at it. With
    /// `hemisphere` false every box within `len` of the origin (and a
    /// margin above rounding) is kept (with its cone), on either side of
    /// the tangent plane. With many boxes (a hall of moving props) only
    /// those an index lists near the origin are looked at (made on the
    /// first look, for the first `len` asked; the same boxes are kept).
    pub fn seen_from(&self, rays: &PointRays, len: f32, hemisphere: bool) -> Vec<SeenBox> {
        let (origin, normal) = (rays.origin(), rays.normal());
        // With many boxes only those the index lists near the origin are
        // looked at: every one the test below keeps is among them.
        let near = (self.boxes.len() >= INDEX_FROM)
            .then(|| self.index.get_or_init(|| BoxIndex::new(&self.boxes, len)))
            .filter(|index| index.len == len)
            .and_then(|index| index.near(origin));
        let keep = |&(lo, hi): &(Vec3A, Vec3A)| {
            let nearest = origin.clamp(lo, hi);
            if !hemisphere {
                // Rays given with their lengths (at most `len`): a box
                // beyond `len` of the origin, with a margin far above
                // the rounding of the slab test (so that no box it
                // would enter is left out), is entered by none.
                let far = origin.abs().max(hi.abs()).max(lo.abs()).max_element();
                let slack = len * 1e-3 + far * (1.0 / (1u32 << 16) as f32);
                return nearest.distance_squared(origin) <= (len + slack) * (len + slack);
            }
            if nearest.distance_squared(origin) > len * len {
                return false;
            }
            // A corner in front of the tangent plane (or on it, or at a
            // height that is not a number: a box reaching to infinity
            // along an axis the normal has no part of may reach).
            box_corners((lo.into(), hi.into())).into_iter().any(|c| {
                let height = normal.dot(Vec3A::from(c) - origin);
                height >= 0.0 || height.is_nan()
            })
        };
        let seen = |(lo, hi)| SeenBox::new(lo, hi, rays);
        match near {
            Some(ids) => (ids.iter())
                .map(|&i| self.boxes[i as usize])
                .filter(keep)
                .map(seen)
                .collect(),
            None => self.boxes.iter().copied().filter(keep).map(seen).collect(),
        }
    }

    /// The distance along the ray from `origin` in unit direction `dir`
    /// at which it first enters any box, if it does before `len`.
    #[cfg(test)]
    fn entry(&self, origin: Vec3A, dir: Vec3A, len: f32) -> Option<f32> {
        let inv = Vec3A::ONE / dir;
        self.boxes
            .iter()
            .filter_map(|&(lo, hi)| slab_entry(lo, hi, origin, dir, inv, len))
            .reduce(f32::min)
    }
}

/// A box of what moves as one point sees it ([`MotionBoxes::seen_from`]):
/// a ray can enter it only if its direction lies in the cone about `axis`
/// holding the box's bounding sphere, and only the point's rays `rays`
/// can point there.
#[derive(Clone, Debug)]
pub struct SeenBox {
    lo: Vec3A,
    hi: Vec3A,
    /// The unit direction to the box's centre (unused where every
    /// direction may enter).
    axis: Vec3A,
    /// The cosine of the cone's half angle (with a margin for rounding):
    /// a direction whose dot product with `axis` is below it misses.
    cos: f32,
    /// The point's rays that can point into the cone.
    rays: std::ops::Range<u32>,
}

impl SeenBox {
    fn new(lo: Vec3A, hi: Vec3A, rays: &PointRays) -> SeenBox {
        let origin = rays.origin();
        let centre = (lo + hi) * 0.5;
        // From the centre as rounded, to the farthest corner: the sphere
        // holds the whole box whatever the rounding of the centre (a
        // half diagonal about a rounded centre can leave a corner out,
        // and far from the origin of the world that rounding is large).
        let radius = (hi - centre).max(centre - lo).length();
        let to = centre - origin;
        let distance = to.length();
        // Within the bounding sphere, or too near it for a cone worth the
        // name (the 1% keeps the arcsine off its steep end), or nothing to
        // go by: every direction may enter. (`axis` is then unused.)
        let every = SeenBox {
            lo,
            hi,
            axis: rays.normal(),
            cos: f32::NEG_INFINITY,
            rays: 0..u32::MAX,
        };
        if !distance.is_finite() || distance <= radius * 1.01 {
            return every;
        }
        // The half angle of the sphere's cone, with a margin far above
        // the rounding of the slab test and of these sums.
        let half = (radius / distance).asin() + 1e-3;
        let axis = to / distance;
        SeenBox {
            lo,
            hi,
            axis,
            cos: half.cos(),
            rays: rays.rays_near(axis, half),
        }
    }

    /// Whether ray `k` of the point can point into the box.
    fn may_hold(&self, k: u32) -> bool {
        self.rays.contains(&k)
    }

    /// The distance along the ray from `origin` in unit direction `dir`
    /// (inverse `inv`) at which it enters the box, if it does before
    /// `len`.
    fn entry(&self, origin: Vec3A, dir: Vec3A, inv: Vec3A, len: f32) -> Option<f32> {
        if self.axis.dot(dir) < self.cos {
            return None;
        }
        slab_entry(self.lo, self.hi, origin, dir, inv, len)
    }
}

/// Where the ray from `origin` along unit `dir` (inverse `inv`) enters
/// the box `lo..hi`, if it does before `len` (0 when it starts inside).
fn slab_entry(
    lo: Vec3A,
    hi: Vec3A,
    origin: Vec3A,
    dir: Vec3A,
    inv: Vec3A,
    len: f32,
) -> Option<f32> {
    let (o, d, inv) = (origin.to_array(), dir.to_array(), inv.to_array());
    let (lo, hi) = (lo.to_array(), hi.to_array());
    let (mut near, mut far) = (0.0f32, len);
    for a in 0..3 {
        if d[a] == 0.0 {
            // Parallel to this slab: inside it or never.
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let (t1, t2) = ((lo[a] - o[a]) * inv[a], (hi[a] - o[a]) * inv[a]);
        near = near.max(t1.min(t2));
        far = far.min(t1.max(t2));
    }
    (near <= far).then_some(near)
}

/// Where a ray first enters any of `seen`, if it does before `len`.
fn seen_entry(seen: &[SeenBox], origin: Vec3A, dir: Vec3A, len: f32) -> Option<f32> {
    let inv = Vec3A::ONE / dir;
    seen.iter()
        .filter_map(|b| b.entry(origin, dir, inv, len))
        .reduce(f32::min)
}

/// The boxes of what moves, held a little larger than they are from one
/// step to the next: while each step's boxes stay inside them (and the
/// same instances move), the envelope is the same. Points still plan
/// their rays against the step's own boxes, but only the rays that reach
/// the envelope (found once while it holds: a static point's rays are
/// fixed, and what moves stays inside); a point none of whose rays
/// reaches it needs no test at all. A rotating wheel's box barely moves,
/// so the points around it test all their rays once, not every step. A
/// box that travels is given room for [`ENVELOPE_STEPS`] steps of its
/// last step's travel, so that an envelope over parts that walk holds
/// for several steps too.
#[derive(Clone, Debug, Default)]
pub struct Envelope {
    /// The instances that moved, ascending, one box each.
    moving: Vec<usize>,
    boxes: Vec<(Vec3, Vec3)>,
    /// The instances that moved in the last step, and their boxes then.
    last: (Vec<usize>, Vec<(Vec3, Vec3)>),
}

/// How much an envelope box is larger than the box it was made for, as a
/// share of that box's diagonal, on every side.
pub const ENVELOPE_MARGIN: f32 = 0.05;

/// The steps of its last step's travel an envelope box leaves room for,
/// on every side, where that is more than [`ENVELOPE_MARGIN`] gives: a
/// point learns which of its rays reach the envelope in its second step
/// under it, so an envelope that holds for fewer steps costs more tests
/// than it saves.
pub const ENVELOPE_STEPS: f32 = 8.0;

impl Envelope {
    /// Takes a step's boxes, one per instance in `moving` (ascending):
    /// keeps the envelope if the same instances move and each box lies
    /// inside its own, else makes a new one, each box grown on every side
    /// by [`ENVELOPE_MARGIN`] of its diagonal or [`ENVELOPE_STEPS`] times
    /// the most its sides moved along that axis in the last step (the
    /// same instance's box then), whichever is more. Returns whether it
    /// changed. (Another instance
    /// moving makes a new one: a point of an instance that moved has
    /// other rays, and what was found against the last no longer holds.)
    pub fn cover(&mut self, moving: &[usize], boxes: &[(Vec3, Vec3)]) -> bool {
        let inside = moving == self.moving
            && boxes.len() == self.boxes.len()
            && boxes
                .iter()
                .zip(&self.boxes)
                .all(|(b, e)| b.0.cmpge(e.0).all() && b.1.cmple(e.1).all());
        let last = std::mem::replace(&mut self.last, (moving.to_vec(), boxes.to_vec()));
        if inside {
            return false;
        }
        // How far each box's sides moved in the last step (none for an
        // instance that did not move then, or a box that is not finite).
        let travel = |n: usize, &(lo, hi): &(Vec3, Vec3)| {
            let j = last.0.binary_search(moving.get(n)?).ok()?;
            let (a, b) = last.1.get(j)?;
            let t = (lo - *a).abs().max((hi - *b).abs());
            t.is_finite().then_some(t)
        };
        self.moving = moving.to_vec();
        self.boxes = boxes
            .iter()
            .enumerate()
            .map(|(n, b)| {
                let m = Vec3::splat(ENVELOPE_MARGIN * (b.1 - b.0).length())
                    .max(travel(n, b).unwrap_or(Vec3::ZERO) * ENVELOPE_STEPS);
                (b.0 - m, b.1 + m)
            })
            .collect();
        true
    }

    /// The envelope's boxes.
    pub fn boxes(&self) -> &[(Vec3, Vec3)] {
        &self.boxes
    }
}

/// What [`reached_rays`] knows of a point beyond its rays, and how far it
/// searches.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReachQuery<'a> {
    /// The rays' directions and lengths (`w`) when they are kept (else
    /// they are drawn from the point's [`PointRays`]).
    pub dirs: Option<&'a [Vec4]>,
    /// The rays' scores of the last trace (closest-hit estimator): a ray
    /// that enters the boxes only beyond what it hit then is not reached,
    /// the hit being static and still nearer. Without them a ray is
    /// reached if its whole length enters a box.
    pub scores: Option<&'a [f32]>,
    /// Only these rays can be reached (those that reach boxes holding
    /// the ones tested, say the envelope's): the others are not tested.
    pub among: Option<Among<'a>>,
    /// Stop at the first reached ray (all that matters when every ray is
    /// traced anyway).
    pub first_only: bool,
}

/// The only rays of a point that can be reached ([`ReachQuery::among`]).
#[derive(Clone, Copy, Debug)]
pub struct Among<'a> {
    /// The rays.
    pub mask: &'a RayMask,
    /// Their directions and lengths (`w`), in the mask's order, when they
    /// are kept (else from [`ReachQuery::dirs`] or drawn).
    pub dirs: Option<&'a [Vec4]>,
}

/// The rays of a point (`rays`, its `count` rays: `rays.count()`) that
/// `motion` can reach, with what `query` knows of them.
pub fn reached_rays(
    rays: &PointRays,
    count: u32,
    motion: &MotionBoxes,
    estimator: Estimator,
    radius: f32,
    query: ReachQuery<'_>,
) -> RayMask {
    let ReachQuery {
        dirs,
        scores,
        among,
        first_only,
    } = query;
    debug_assert_eq!(count, rays.count(), "a point's rays are counted by its own");
    let mut mask = RayMask::none(count);
    if motion.is_empty() {
        return mask;
    }
    // Only the boxes its hemisphere can reach (closest-hit rays and
    // Laine-Karras ones are no longer than the radius), and of each the
    // cone its rays can enter it by. Rays given `among` are tested
    // against every box within their reach, on either side.
    let seen = motion.seen_from(rays, radius, among.is_none());
    if seen.is_empty() {
        return mask;
    }
    // Whether ray `k` (its direction and length) is reached.
    let reached = |k: u32, (dir, len): (Vec3A, f32)| {
        let Some(t_in) = seen_entry(&seen, rays.origin(), dir, len) else {
            return false;
        };
        let hit_before = match (estimator, scores.and_then(|s| s.get(k as usize))) {
            // The last trace hit at `score * R` (less the lead the tracer
            // takes off): a box entered beyond it changes nothing.
            (Estimator::ClosestHit, Some(&s)) if s < 1.0 => t_in > s * radius + 2.0 * RAY_LEAD,
            _ => false,
        };
        !hit_before
    };
    let kept = |k: u32, among: Option<&Vec4>| {
        among
            .or_else(|| dirs.and_then(|d| d.get(k as usize)))
            .map(|d| (Vec3A::from(d.truncate()), d.w))
    };
    // A ray pointing into no box's cone is not drawn.
    let may_reach = |k: u32| seen.iter().any(|b| b.may_hold(k));
    let ray = |k: u32, among: Option<&Vec4>| match kept(k, among) {
        Some(r) => Some(r),
        None => may_reach(k).then(|| rays.ray(k)),
    };
    // Tests ray `k`; whether to stop.
    let mut test = |k: u32, among_dir: Option<&Vec4>| {
        if ray(k, among_dir).is_some_and(|r| reached(k, r)) {
            mask.set(k);
            return first_only;
        }
        false
    };
    match among {
        // Only these rays can be reached.
        Some(among) => {
            for (j, k) in among.mask.iter().enumerate() {
                if test(k, among.dirs.and_then(|d| d.get(j))) {
                    break;
                }
            }
        }
        None => {
            for k in 0..count {
                if test(k, None) {
                    break;
                }
            }
        }
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::ao::AoParams;

    #[test]
    fn an_envelope_holds_while_boxes_stay_inside_it() {
        let mut e = Envelope::default();
        let b = (Vec3::ZERO, Vec3::ONE);
        assert!(e.cover(&[3], &[b]), "the first boxes make one");
        let m = ENVELOPE_MARGIN * 3f32.sqrt();
        assert!((e.boxes()[0].0 - Vec3::splat(-m)).abs().max_element() < 1e-6);
        // A box that moved less than the margin: the same envelope.
        let nudged = (Vec3::splat(0.01), Vec3::splat(1.01));
        assert!(!e.cover(&[3], &[nudged]));
        // The same box, but another instance moves in it: a new one.
        assert!(e.cover(&[4], &[nudged]));
        // Out of it, or another count of boxes: a new one.
        assert!(e.cover(&[4], &[(Vec3::splat(0.5), Vec3::splat(1.5))]));
        assert!(e.cover(&[3, 4], &[b, b]));
        assert!(e.cover(&[], &[]));
        assert!(
            !e.cover(&[], &[]),
            "nothing moving again: the same (empty) envelope"
        );
    }

    #[test]
    fn an_envelope_over_a_part_that_travels_leaves_it_room_for_several_steps() {
        // A unit box sliding 2 cm a step along x, and a wheel's box
        // turning in place beside it, for 64 steps.
        let mut e = Envelope::default();
        let mut renewed = 0;
        for step in 0..64 {
            let x = 0.02 * step as f32;
            let slid = (Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0));
            let wheel = (Vec3::new(5.0, 0.0, 0.0), Vec3::new(6.0, 1.0, 1.0));
            renewed += u32::from(e.cover(&[2, 7], &[slid, wheel]));
            // Whatever it does, each box lies inside its own.
            for (b, env) in [slid, wheel].iter().zip(e.boxes()) {
                assert!(
                    b.0.cmpge(env.0).all() && b.1.cmple(env.1).all(),
                    "step {step}"
                );
            }
            // The wheel's box did not travel: its margin alone.
            let m = ENVELOPE_MARGIN * 3f32.sqrt();
            assert!(
                (e.boxes()[1].0 - (wheel.0 - Vec3::splat(m)))
                    .abs()
                    .max_element()
                    < 1e-5
            );
        }
        // The margin alone (8.7 cm) holds the sliding box 4 steps: 13
        // envelopes in 64 steps. With room for 8 steps of 2 cm, at most
        // one in 8 steps after the first two.
        assert!(renewed <= 2 + 64 / 8, "{renewed} envelopes in 64 steps");
        assert!(renewed >= 64 / 16, "{renewed}: room for more than 16 steps");
        // The sliding box stops and the wheel's box slides: the wheel's
        // room is its own travel, not that of the box before it in the
        // last step's list.
        let wheel = |x: f32| (Vec3::new(5.0 + x, 0.0, 0.0), Vec3::new(6.0 + x, 1.0, 1.0));
        assert!(e.cover(&[7], &[wheel(0.0)]), "other instances move");
        assert!(e.cover(&[7], &[wheel(0.1)]), "out of its 5% margin");
        let room = e.boxes()[0].1.x - wheel(0.1).1.x;
        assert!(
            (room - 0.8).abs() < 1e-4,
            "room {room} for 8 steps of 10 cm"
        );
    }

    #[test]
    fn a_box_reaching_to_infinity_is_seen_from_a_floor() {
        // A floor point (its normal has no part along x) under a box
        // that reaches to infinity along x: its corners' heights are not
        // numbers, and the box is still seen.
        let p = AoParams {
            rays: 32,
            ..AoParams::default()
        };
        let rays = PointRays::new(0, Vec3::ZERO, Vec3::Y, &p).expect("rays");
        let b = (
            Vec3::new(f32::NEG_INFINITY, 0.1, -0.2),
            Vec3::new(f32::INFINITY, 0.3, 0.2),
        );
        let boxes = MotionBoxes::new([b], 0.0);
        let mask = reached_rays(
            &rays,
            32,
            &boxes,
            Estimator::ClosestHit,
            p.radius,
            ReachQuery::default(),
        );
        assert!(!mask.is_empty(), "the rays straight up enter the box");
    }

    /// A point, a normal, 1 to 3 boxes around it, a ray count and an
    /// estimator, drawn for `case`: boxes near and far, large and thin,
    /// some holding the point.
    fn drawn_case(case: u32) -> (PointRays, u32, MotionBoxes, Estimator) {
        let r = |j: u32| crate::random::uniform(7, case, j);
        let v = |j: u32| Vec3::new(r(j), r(j + 1), r(j + 2)) * 2.0 - 1.0;
        let count = [8, 32, 64, 100][case as usize % 4];
        let estimator = if case.is_multiple_of(3) {
            Estimator::LaineKarras
        } else {
            Estimator::ClosestHit
        };
        let p = AoParams {
            rays: count,
            estimator,
            ..AoParams::default()
        };
        let rays = PointRays::new(case, v(0), v(3), &p).expect("rays");
        let boxes = (0..1 + case % 3).map(|b| {
            let centre = v(0) + v(10 + 10 * b) * 0.8;
            let half = (v(13 + 10 * b) + 1.0) * 0.5 * [0.02, 0.1, 0.4][(case / 4 % 3) as usize];
            (centre - half, centre + half)
        });
        (rays, count, MotionBoxes::new(boxes, 0.0), estimator)
    }

    #[test]
    fn many_boxes_are_looked_up_by_place_and_reach_the_same_rays() {
        // 40 to 100 boxes about a point (past the count from which
        // `seen_from` looks them up in its index), some huge (listed
        // everywhere), far from the origin of the world in some cases:
        // every ray, drawn or given, reaches what it reaches against
        // every box one by one.
        let (mut left_out, mut reached) = (0, 0);
        for case in 0..400u32 {
            let (rays, count, _, estimator) = drawn_case(case);
            let r = |j: u32| crate::random::uniform(11, case, j);
            let v = |j: u32| Vec3::new(r(j), r(j + 1), r(j + 2)) * 2.0 - 1.0;
            let offset = if case % 5 == 0 {
                Vec3::splat(3000.0)
            } else {
                Vec3::ZERO
            };
            let n = 40 + case % 61;
            let boxes: Vec<(Vec3, Vec3)> = (0..n)
                .map(|b| {
                    let centre = Vec3::from(rays.origin()) + v(10 * b) * 3.0;
                    let size = if b % 17 == 0 { 40.0 } else { 0.3 };
                    let half = (v(10 * b + 3) + 1.0) * 0.5 * size;
                    (centre - half, centre + half)
                })
                .collect();
            // The same point moved far out with its boxes.
            let p = AoParams {
                rays: count,
                estimator,
                ..AoParams::default()
            };
            let rays = PointRays::new(
                case,
                Vec3::from(rays.origin()) + offset,
                rays.normal().into(),
                &p,
            )
            .expect("rays");
            let boxes = MotionBoxes::new(
                boxes.iter().map(|&(lo, hi)| (lo + offset, hi + offset)),
                0.0,
            );
            assert!(boxes.boxes.len() >= INDEX_FROM);
            let drawn: Vec<Vec4> = (0..count)
                .map(|k| {
                    let (d, len) = rays.ray(k);
                    Vec3::from(d).extend(len)
                })
                .collect();
            let all = RayMask::all(count);
            let reach = |q: ReachQuery<'_>| reached_rays(&rays, count, &boxes, estimator, 0.6, q);
            let (plain, given) = (
                reach(ReachQuery::default()),
                reach(ReachQuery {
                    among: Some(Among {
                        mask: &all,
                        dirs: Some(&drawn),
                    }),
                    ..ReachQuery::default()
                }),
            );
            for k in 0..count {
                let (d, len) = rays.ray(k);
                let enters = boxes.entry(rays.origin(), d, len).is_some();
                assert_eq!(plain.has(k), enters, "case {case}, ray {k}");
                assert_eq!(given.has(k), enters, "case {case}, ray {k}, given");
            }
            let index = boxes.index.get().expect("looked up by place");
            let near = index.near(rays.origin()).expect("on the grid");
            left_out += usize::from(near.len() < boxes.boxes.len());
            reached += usize::from(!plain.is_empty());
        }
        // The index leaves boxes out, and rays do reach boxes.
        assert!(left_out > 300 && reached > 100, "{left_out} {reached}");
        // Looked up from anywhere, near cube edges too, the index lists
        // every box within reach.
        let r = |j: u32| crate::random::uniform(13, 0, j);
        let boxes: Vec<(Vec3A, Vec3A)> = (0..200)
            .map(|b| {
                let c = Vec3A::new(r(6 * b), r(6 * b + 1), r(6 * b + 2)) * 10.0;
                let h = Vec3A::new(r(6 * b + 3), r(6 * b + 4), r(6 * b + 5)) * 0.4;
                (c - h, c + h)
            })
            .collect();
        let index = BoxIndex::new(&boxes, 0.6);
        let mut within = 0;
        for q in 0..20_000u32 {
            let u = |a: u32| crate::random::uniform(17, q, a);
            // Half of them within 1% of a cube's edge.
            let mut p = Vec3A::new(u(0), u(1), u(2)) * 10.0;
            if q % 2 == 0 {
                p = (p / index.cell).round() * index.cell
                    + (Vec3A::new(u(3), u(4), u(5)) - 0.5) * 0.012;
            }
            let near = index.near(p).expect("on the grid");
            for (i, &(lo, hi)) in boxes.iter().enumerate() {
                if p.clamp(lo, hi).distance(p) <= 0.6 * 1.001 {
                    within += 1;
                    assert!(near.binary_search(&(i as u32)).is_ok(), "box {i} from {p}");
                }
            }
        }
        assert!(within > 10_000, "{within}");
        // Boxes spanning most of the grid's range, or past it, or not
        // finite (a file's wild transform) are looked at from everywhere.
        let wild = [
            (Vec3A::splat(-1e9), Vec3A::splat(1e9)),
            (Vec3A::splat(1e12), Vec3A::splat(1e12 + 1.0)),
            (Vec3A::splat(f32::NAN), Vec3A::ONE),
            (Vec3A::ZERO, Vec3A::splat(f32::INFINITY)),
            (Vec3A::ZERO, Vec3A::ONE),
        ];
        let index = BoxIndex::new(&wild, 0.6);
        assert_eq!(index.everywhere, vec![0, 1, 2, 3]);
        assert_eq!(
            index.near(Vec3A::splat(0.5)).as_deref(),
            Some(&[0, 1, 2, 3, 4][..])
        );
        assert_eq!(index.near(Vec3A::splat(f32::NAN)), None);
    }

    #[test]
    fn joined_boxes_are_reached_by_every_ray_that_reaches_a_box_of_a_set() {
        // A box sliding step by step (overlapping boxes) and other sets
        // drawn at random: every ray that enters a box of some set enters
        // a joined box, drawn rays and rays through box corners alike.
        let (mut merged, mut tested) = (0, 0);
        for case in 0..2000 {
            let (rays, count, first, _) = drawn_case(case);
            let r = |j: u32| crate::random::uniform(11, case, j);
            let step = Vec3A::new(r(0), r(1), r(2)) * 0.1 - 0.05;
            let sets: Vec<MotionBoxes> = (0..1 + case % 5)
                .map(|s| {
                    let (_, _, drawn, _) = drawn_case(case + 7919 * s);
                    let slid = first
                        .boxes
                        .iter()
                        .map(|&(lo, hi)| (lo + step * s as f32, hi + step * s as f32));
                    let boxes = slid.chain(drawn.boxes.iter().copied().take(s as usize % 2));
                    MotionBoxes {
                        boxes: boxes.collect(),
                        index: OnceLock::new(),
                    }
                })
                .collect();
            let joined = MotionBoxes::joined(&sets);
            let all = sets.iter().map(|m| m.boxes.len()).sum::<usize>();
            assert!(joined.boxes.len() <= all, "case {case}");
            merged += usize::from(joined.boxes.len() < all);
            let origin = rays.origin();
            let corners = sets
                .iter()
                .flat_map(|m| m.boxes.iter())
                .flat_map(|&(lo, hi)| {
                    [lo, hi, (lo + hi) * 0.5].map(|c| {
                        let d = c - origin;
                        (d.normalize_or_zero(), d.length() * 1.01)
                    })
                });
            let drawn = (0..count).map(|k| rays.ray(k));
            for (dir, len) in drawn.chain(corners) {
                if dir == Vec3A::ZERO {
                    continue;
                }
                if sets.iter().any(|m| m.entry(origin, dir, len).is_some()) {
                    tested += 1;
                    assert!(
                        joined.entry(origin, dir, len).is_some(),
                        "case {case}: a ray enters a box of a set, no joined box"
                    );
                }
            }
        }
        assert!(
            merged > 500 && tested > 5000,
            "{merged} cases merged, {tested} rays"
        );
    }

    #[test]
    fn cones_leave_out_only_rays_that_enter_no_box() {
        // Every ray against every box, as before cones: what reached_rays
        // must still find, ray for ray, drawing the rays or given them,
        // among all rays or some.
        let (mut partial, mut pruned, mut beyond) = (0, 0, 0);
        for case in 0..3000 {
            let (rays, count, boxes, estimator) = drawn_case(case);
            let drawn: Vec<Vec4> = (0..count)
                .map(|k| {
                    let (d, len) = rays.ray(k);
                    Vec3::from(d).extend(len)
                })
                .collect();
            let enters: Vec<bool> = (0..count)
                .map(|k| {
                    let (d, len) = rays.ray(k);
                    boxes.entry(rays.origin(), d, len).is_some()
                })
                .collect();
            let reach = |q: ReachQuery<'_>| reached_rays(&rays, count, &boxes, estimator, 0.6, q);
            let r = reach(ReachQuery::default());
            for k in 0..count {
                assert_eq!(r.has(k), enters[k as usize], "case {case}, ray {k}");
            }
            let kept = reach(ReachQuery {
                dirs: Some(&drawn),
                ..ReachQuery::default()
            });
            assert_eq!(kept, r, "case {case}: directions given");
            let mut odd = RayMask::none(count);
            (1..count).step_by(2).for_each(|k| odd.set(k));
            let odd_dirs: Vec<Vec4> = odd.iter().map(|k| drawn[k as usize]).collect();
            for dirs in [None, Some(&odd_dirs[..])] {
                let among = reach(ReachQuery {
                    among: Some(Among { mask: &odd, dirs }),
                    ..ReachQuery::default()
                });
                for k in 0..count {
                    let want = enters[k as usize] && k % 2 == 1;
                    assert_eq!(among.has(k), want, "case {case}, ray {k} among odd ones");
                }
            }
            partial += usize::from(!r.is_empty() && r.count() < count);
            let seen = boxes.seen_from(&rays, 0.6, true);
            pruned +=
                usize::from(!seen.is_empty() && seen.iter().all(|b| b.rays.len() < count as usize));
            // Rays given `among` skip the boxes beyond their reach.
            beyond += usize::from(boxes.seen_from(&rays, 0.6, false).len() < boxes.boxes.len());
        }
        // The cases are worth the name: many reach some rays, not all,
        // in many the cones leave rays out untested, and in many boxes
        // lie beyond the rays given.
        assert!(
            partial > 500 && pruned > 300 && beyond > 300,
            "{partial} {pruned} {beyond}"
        );
    }

    #[test]
    fn a_cone_holds_every_corner_of_its_box_far_from_the_origin_of_the_world() {
        // Where coordinates are large, the box's centre rounds. A point
        // looks at a corner along the line that grazes the box's sphere
        // there (the edge of the cone), and the cone must still hold
        // every ray the slab test takes.
        let mut tested = 0;
        for (case, offset) in [0.0f32, 30.0, 1e3, 1e4, 6e4].into_iter().enumerate() {
            for j in 0..400u32 {
                let r = |n: u32| crate::random::uniform(9, case as u32 * 1000 + j, n);
                let v = |n: u32| Vec3::new(r(n), r(n + 1), r(n + 2)) * 2.0 - 1.0;
                let base = Vec3::splat(offset) + v(0) * offset.max(1.0) * 0.25;
                // Boxes as large as a part, and as thin as their padding
                // (a flat or tiny part), where the centre's rounding
                // weighs most.
                let size = v(3).abs() * [0.6, 2e-3, 0.0][(j / 8 % 3) as usize];
                let boxes = MotionBoxes::new([(base, base + size)], 4.0 * RAY_LEAD);
                let (lo, hi) = boxes.boxes[0];
                let c = (j % 8) as usize;
                let corner = Vec3::new(
                    if c & 1 == 0 { lo.x } else { hi.x },
                    if c & 2 == 0 { lo.y } else { hi.y },
                    if c & 4 == 0 { lo.z } else { hi.z },
                );
                // Away from the corner, square to the sphere's radius
                // there: the line back to the corner grazes the sphere.
                let out = (corner - (Vec3::from(lo) + Vec3::from(hi)) * 0.5).normalize();
                let side = out.any_orthonormal_pair().0;
                let sphere = (hi - lo).length() * 0.5;
                let at = corner + side * sphere * (0.15 + 0.5 * r(9));
                let p = AoParams {
                    rays: 32,
                    ..AoParams::default()
                };
                let rays = PointRays::new(j, at, -side, &p).expect("rays");
                let seen = boxes.seen_from(&rays, 10.0, false);
                let o = rays.origin();
                let corner = Vec3A::from(corner);
                for inside in [0.0, 1e-4, 1e-3] {
                    let aim = corner + ((lo + hi) * 0.5 - corner) * inside;
                    let Some(dir) = (aim - o).try_normalize() else {
                        continue;
                    };
                    let inv = Vec3A::ONE / dir;
                    if slab_entry(lo, hi, o, dir, inv, 10.0).is_none() {
                        continue;
                    }
                    tested += 1;
                    assert!(
                        seen_entry(&seen, o, dir, 10.0).is_some(),
                        "offset {offset}, case {j}, corner {c}, inside {inside}"
                    );
                }
            }
        }
        assert!(tested > 3000, "{tested}");
    }

    #[test]
    fn the_rays_near_a_direction_lie_in_the_run_given() {
        for case in 0..3000 {
            let (rays, count, ..) = drawn_case(case);
            let r = |j: u32| crate::random::uniform(8, case, j);
            let axis = (Vec3A::new(r(0), r(1), r(2)) * 2.0 - 1.0).normalize();
            let half = r(3) * r(3) * std::f32::consts::PI;
            let run = rays.rays_near(axis, half);
            for k in 0..count {
                let (d, _) = rays.ray(k);
                if d.dot(axis).clamp(-1.0, 1.0).acos() <= half {
                    assert!(run.contains(&k), "case {case}: ray {k} outside {run:?}");
                }
            }
        }
        // Straight along the normal, a narrow cone holds only the first
        // rays (those nearest the normal).
        let (rays, count, ..) = drawn_case(1);
        assert!(rays.rays_near(rays.normal(), 0.1).end < count / 4);
    }

    #[test]
    fn masks_count_and_combine() {
        let mut m = RayMask::none(70);
        assert!(m.is_empty());
        m.set(3);
        m.set(69);
        m.set(70); // past the end: ignored
        assert_eq!(m.count(), 2);
        assert!(m.has(69) && !m.has(4));
        assert_eq!(m.iter().collect::<Vec<_>>(), vec![3, 69]);
        let mut all = RayMask::all(70);
        assert_eq!(all.count(), 70);
        all.union(&m);
        assert_eq!(all.count(), 70);
    }

    #[test]
    fn rays_reach_a_box_above_and_not_one_below() {
        let p = AoParams {
            rays: 64,
            ..AoParams::default()
        };
        let rays = PointRays::new(7, Vec3::ZERO, Vec3::Y, &p).unwrap();
        let above = MotionBoxes::new(
            [(Vec3::new(-0.2, 0.1, -0.2), Vec3::new(0.2, 0.3, 0.2))],
            0.0,
        );
        let below = MotionBoxes::new(
            [(Vec3::new(-1.0, -0.5, -1.0), Vec3::new(1.0, -0.1, 1.0))],
            0.0,
        );
        let far = MotionBoxes::new([(Vec3::splat(5.0), Vec3::splat(6.0))], 0.0);
        let reach = |m: &MotionBoxes, q: ReachQuery<'_>| {
            reached_rays(&rays, 64, m, Estimator::ClosestHit, 0.6, q)
        };
        let r = |m: &MotionBoxes| reach(m, ReachQuery::default());
        let up = r(&above);
        assert!(up.count() > 10 && up.count() < 64, "{}", up.count());
        assert!(r(&below).is_empty(), "the hemisphere faces away");
        assert!(r(&far).is_empty(), "beyond the radius");
        // Each reached ray does enter the box; each other one does not.
        for k in 0..64 {
            let (d, len) = rays.ray(k);
            let enters = above.entry(rays.origin(), d, len).is_some();
            assert_eq!(enters, up.has(k), "ray {k}");
        }
        // A ray whose last hit was nearer than the box is not reached.
        let dirs: Vec<Vec4> = (0..64)
            .map(|k| {
                let (d, len) = rays.ray(k);
                Vec3::from(d).extend(len)
            })
            .collect();
        let scores = vec![0.1f32; 64]; // hits at 6 cm, the box at 10 cm and up
        let kept = reach(
            &above,
            ReachQuery {
                dirs: Some(&dirs),
                scores: Some(&scores),
                ..ReachQuery::default()
            },
        );
        assert!(kept.is_empty(), "{}", kept.count());
        let open = vec![1.0f32; 64];
        let again = reach(
            &above,
            ReachQuery {
                dirs: Some(&dirs),
                scores: Some(&open),
                ..ReachQuery::default()
            },
        );
        assert_eq!(again, up);
        // Among some rays only: the reached ones of those.
        let mut half = RayMask::none(64);
        for k in (0..64).step_by(2) {
            half.set(k);
        }
        let among = reach(
            &above,
            ReachQuery {
                among: Some(Among {
                    mask: &half,
                    dirs: None,
                }),
                ..ReachQuery::default()
            },
        );
        for k in 0..64 {
            assert_eq!(among.has(k), up.has(k) && k % 2 == 0, "ray {k}");
        }
        // The same with their directions kept, in the mask's order.
        let half_dirs: Vec<Vec4> = half.iter().map(|k| dirs[k as usize]).collect();
        let kept_among = reach(
            &above,
            ReachQuery {
                among: Some(Among {
                    mask: &half,
                    dirs: Some(&half_dirs),
                }),
                ..ReachQuery::default()
            },
        );
        assert_eq!(kept_among, among);
        // The first reached ray only.
        let first = reach(
            &above,
            ReachQuery {
                first_only: true,
                ..ReachQuery::default()
            },
        );
        assert_eq!(first.count(), 1);
        assert!((0..64).find(|&k| up.has(k)).is_some_and(|k| first.has(k)));
        // A box behind the tangent plane, within the radius: not in the
        // hemisphere.
        assert!(below.seen_from(&rays, 0.6, true).is_empty());
        assert!(!above.seen_from(&rays, 0.6, true).is_empty());
    }
}
