//! Which rays of a static point a step's motion can reach: a ray whose
//! segment enters none of the boxes the moving instances occupied before
//! and after the step hits what it hit before, so its score is unchanged,
//! bit for bit (the same ray against the same static triangles). A point
//! none of whose rays can be reached keeps its AO without a trace; one
//! with some re-traces only those when its other rays' scores are kept
//! ([`super::ray_cache`]).

use glam::{Vec3, Vec3A, Vec4};

use crate::trace::ao::{Estimator, PointRays};
use crate::trace::geometry::RAY_LEAD;

/// A set of rays of one point, one bit per ray.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RayMask {
    rays: u32,
    words: Vec<u64>,
}

impl RayMask {
    /// No ray of `rays`.
    pub fn none(rays: u32) -> RayMask {
        RayMask {
            rays,
            words: vec![0; (rays as usize).div_ceil(64)],
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

    /// Adds ray `k` (of those the mask was made for; others are ignored).
    pub fn set(&mut self, k: u32) {
        if k >= self.rays {
            return;
        }
        if let Some(w) = self.words.get_mut(k as usize / 64) {
            *w |= 1 << (k % 64);
        }
    }

    /// Whether ray `k` is in the set.
    pub fn has(&self, k: u32) -> bool {
        self.words
            .get(k as usize / 64)
            .is_some_and(|w| w & (1 << (k % 64)) != 0)
    }

    /// Adds every ray of `other`.
    pub fn union(&mut self, other: &RayMask) {
        if self.words.len() < other.words.len() {
            self.words.resize(other.words.len(), 0);
            self.rays = other.rays;
        }
        for (a, b) in self.words.iter_mut().zip(&other.words) {
            *a |= b;
        }
    }

    /// Rays in the set.
    pub fn count(&self) -> u32 {
        self.words.iter().map(|w| w.count_ones()).sum()
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.words.iter().all(|&w| w == 0)
    }

    /// The rays in the set, ascending.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.words.iter().enumerate().flat_map(|(w, &bits)| {
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
        self.words.capacity() as u64 * 8
    }
}

/// The world boxes a step's motion occupied: per moving or deforming
/// instance, its bounds before and after the step together, padded
/// against rounding in the ray-box test.
#[derive(Clone, Debug, Default)]
pub struct MotionBoxes {
    boxes: Vec<(Vec3A, Vec3A)>,
}

impl MotionBoxes {
    /// The boxes, each padded by `pad` plus a part that grows with its
    /// coordinates (so that rounding in the slab test never misses a
    /// triangle the tracer would hit).
    pub fn new(boxes: impl IntoIterator<Item = (Vec3, Vec3)>, pad: f32) -> MotionBoxes {
        MotionBoxes {
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

    /// The boxes a hemisphere of rays can enter: those within `len` of
    /// `origin` with a corner on the side `normal` faces. A point whose
    /// hemisphere reaches none needs no ray tested (the reach of item 3 of
    /// issue 20: not only the sphere around it).
    pub fn in_hemisphere(&self, origin: Vec3A, normal: Vec3A, len: f32) -> MotionBoxes {
        let boxes = self
            .boxes
            .iter()
            .copied()
            .filter(|&(lo, hi)| {
                let nearest = origin.clamp(lo, hi);
                if nearest.distance_squared(origin) > len * len {
                    return false;
                }
                // A corner in front of the tangent plane (or on it).
                let c = (0..8).map(|k| {
                    Vec3A::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    )
                });
                c.into_iter().any(|c| normal.dot(c - origin) >= 0.0)
            })
            .collect();
        MotionBoxes { boxes }
    }

    /// The distance along the ray from `origin` in unit direction `dir`
    /// at which it first enters any box, if it does before `len`.
    fn entry(&self, origin: Vec3A, dir: Vec3A, len: f32) -> Option<f32> {
        let (o, d) = (origin.to_array(), dir.to_array());
        let inv = [1.0 / d[0], 1.0 / d[1], 1.0 / d[2]];
        let mut best: Option<f32> = None;
        'boxes: for &(lo, hi) in &self.boxes {
            let (lo, hi) = (lo.to_array(), hi.to_array());
            let (mut near, mut far) = (0.0f32, len);
            for a in 0..3 {
                if d[a] == 0.0 {
                    // Parallel to this slab: inside it or never.
                    if o[a] < lo[a] || o[a] > hi[a] {
                        continue 'boxes;
                    }
                    continue;
                }
                let (t1, t2) = ((lo[a] - o[a]) * inv[a], (hi[a] - o[a]) * inv[a]);
                near = near.max(t1.min(t2));
                far = far.min(t1.max(t2));
            }
            if near <= far && best.is_none_or(|t| near < t) {
                best = Some(near);
            }
        }
        best
    }
}

/// The boxes of what moves, held a little larger than they are from one
/// step to the next: while each step's boxes stay inside them (and the
/// same instances move), the envelope is the same. Points still plan
/// their rays against the step's own boxes, but only the rays that reach
/// the envelope (found once while it holds: a static point's rays are
/// fixed, and what moves stays inside); a point none of whose rays
/// reaches it needs no test at all. A rotating wheel's box barely moves,
/// so the points around it test all their rays once, not every step.
#[derive(Clone, Debug, Default)]
pub struct Envelope {
    /// The instances that moved, ascending, one box each.
    moving: Vec<usize>,
    boxes: Vec<(Vec3, Vec3)>,
}

/// How much an envelope box is larger than the box it was made for, as a
/// share of that box's diagonal, on every side.
pub const ENVELOPE_MARGIN: f32 = 0.05;

impl Envelope {
    /// Takes a step's boxes, one per instance in `moving` (ascending):
    /// keeps the envelope if the same instances move and each box lies
    /// inside its own, else makes a new one, each box grown by
    /// [`ENVELOPE_MARGIN`]. Returns whether it changed. (Another instance
    /// moving makes a new one: a point of an instance that moved has
    /// other rays, and what was found against the last no longer holds.)
    pub fn cover(&mut self, moving: &[usize], boxes: &[(Vec3, Vec3)]) -> bool {
        let inside = moving == self.moving
            && boxes.len() == self.boxes.len()
            && boxes
                .iter()
                .zip(&self.boxes)
                .all(|(b, e)| b.0.cmpge(e.0).all() && b.1.cmple(e.1).all());
        if inside {
            return false;
        }
        self.moving = moving.to_vec();
        self.boxes = boxes
            .iter()
            .map(|&(lo, hi)| {
                let m = Vec3::splat(ENVELOPE_MARGIN * (hi - lo).length());
                (lo - m, hi + m)
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

/// The rays of a point (`rays`, its `count` rays) that `motion` can
/// reach, with what `query` knows of them.
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
    let mut mask = RayMask::none(count);
    if motion.is_empty() {
        return mask;
    }
    // Whether ray `k` (its direction and length) is reached.
    let reached = |motion: &MotionBoxes, k: u32, (dir, len): (Vec3A, f32)| {
        let Some(t_in) = motion.entry(rays.origin(), dir, len) else {
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
    let ray =
        |k: u32, kept: Option<&Vec4>| match kept.or_else(|| dirs.and_then(|d| d.get(k as usize))) {
            Some(d) => (Vec3A::from(d.truncate()), d.w),
            None => rays.ray(k),
        };
    if let Some(among) = among {
        // Few rays: each against every box (a ray enters no box its
        // hemisphere or length cannot reach).
        for (j, k) in among.mask.iter().enumerate() {
            if reached(motion, k, ray(k, among.dirs.and_then(|d| d.get(j)))) {
                mask.set(k);
                if first_only {
                    break;
                }
            }
        }
        return mask;
    }
    // Only the boxes its hemisphere can reach (closest-hit rays and
    // Laine-Karras ones are no longer than the radius).
    let motion = &motion.in_hemisphere(rays.origin(), rays.normal(), radius);
    if motion.is_empty() {
        return mask;
    }
    for k in 0..count {
        if reached(motion, k, ray(k, None)) {
            mask.set(k);
            if first_only {
                break;
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
        assert!(below.in_hemisphere(rays.origin(), Vec3A::Y, 0.6).is_empty());
        assert!(!above.in_hemisphere(rays.origin(), Vec3A::Y, 0.6).is_empty());
    }
}
