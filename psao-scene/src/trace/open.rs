//! Points whose rays can hit nothing: a point's rays count hits out to
//! the AO radius from their origin, in the hemisphere about its normal,
//! so every hit lies in the *half ball* over the point ([`HalfBall`]).
//! When no triangle reaches it, every ray misses and the point's AO is 1
//! exactly, known without casting a ray
//! ([`PointRays::surely_open`](super::ao::PointRays::surely_open)).
//!
//! The tests only rule triangles out, each with a margin for f32
//! rounding: of the rays' directions (a ten-thousandth of the radius),
//! of coordinates far from the world's origin or from a placed layer's,
//! and of the hit test itself, whose error grows with the distance from
//! the ray to the triangle's corners (so with the triangle's size).
//! Anything not finite, and any triangle whose plane is not well defined
//! (a needle) or passes within the margin of the rays' origin, is kept
//! in. A triangle kept in is not necessarily hit: a point whose rays all
//! miss may still be traced, but one said to be open is open (the tests
//! below draw the cases where rounding mattered: large triangles, far
//! local coordinates, a ray offset of nearly nothing).

use glam::{Affine3A, Vec3A};
use obvhs::aabb::Aabb;

/// The share of a distance that f32 rounding of coordinates and of the
/// hit test at that distance stays under, with room to spare (2^-19: 32
/// units in the last place).
const ROUNDING: f32 = 1.0 / (1u32 << 19) as f32;

/// Where a point's rays can hit (see the module): within `reach` of
/// `origin` and no more than `below` under the plane through `origin`
/// normal to `normal`, along directions that rise from the plane at
/// least as steeply as `rise` (the least cosine between a ray and the
/// normal). In a layer's own space ([`HalfBall::placed`]) the normal is
/// not a unit one and the reach covers the world's ball; only
/// [`HalfBall::may_hold`] and [`HalfBall::under`] are used there.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HalfBall {
    origin: Vec3A,
    normal: Vec3A,
    reach: f32,
    below: f32,
    rise: f32,
}

impl HalfBall {
    /// The half ball of rays from `origin` about the unit `normal` out to
    /// `radius`, each rising at least `rise` (a cosine).
    pub fn new(origin: Vec3A, normal: Vec3A, radius: f32, rise: f32) -> HalfBall {
        let below = radius * 1e-4 + origin.abs().max_element() * ROUNDING;
        HalfBall {
            origin,
            normal,
            reach: radius + below,
            below,
            rise: rise.clamp(0.0, 1.0),
        }
    }

    /// The box it lies in.
    pub fn bounds(&self) -> (glam::Vec3, glam::Vec3) {
        let r = Vec3A::splat(self.reach);
        ((self.origin - r).into(), (self.origin + r).into())
    }

    /// The same region with margins `extra` wider (below the plane and
    /// beyond the reach).
    pub fn widened(&self, extra: f32) -> HalfBall {
        let extra = extra.max(0.0);
        HalfBall {
            reach: self.reach + extra,
            below: self.below + extra,
            ..*self
        }
    }

    /// The same region in the space of a layer placed by `to_world`
    /// (`to_local` its inverse), for [`HalfBall::may_hold`] and
    /// [`HalfBall::under`]: heights above the plane are the world's (the
    /// normal is carried by the transpose of the linear part), the margin
    /// grows with the rounding of the layer's own coordinates there, as
    /// `to_world` carries it to the world, and the reach by the most
    /// `to_local` can stretch a length (at most its Frobenius norm).
    /// Returns the region and the margin added, which a test of the
    /// layer's triangles in world space must allow too.
    pub fn placed(&self, to_world: &Affine3A, to_local: &Affine3A) -> (HalfBall, f32) {
        let frobenius = |m: &glam::Mat3A| {
            (m.x_axis.length_squared() + m.y_axis.length_squared() + m.z_axis.length_squared())
                .sqrt()
        };
        let origin = to_local.transform_point3a(self.origin);
        let extra = origin.abs().max_element() * frobenius(&to_world.matrix3) * ROUNDING;
        let local = HalfBall {
            origin,
            normal: to_world.matrix3.transpose() * self.normal,
            reach: (self.reach + extra) * frobenius(&to_local.matrix3),
            below: self.below + extra,
            rise: self.rise,
        };
        (local, extra)
    }

    /// The margin for rounding at points up to `spread` (along any axis)
    /// from the origin: the hit test's error grows with it.
    fn slack(&self, spread: f32) -> f32 {
        spread * ROUNDING
    }

    /// Whether the box `b` may hold a point of the region: not when it
    /// lies farther than the reach, nor wholly further below the plane
    /// (margins as wide as for any triangle it holds).
    pub fn may_hold(&self, b: &Aabb) -> bool {
        let spread = (b.min - self.origin)
            .abs()
            .max((b.max - self.origin).abs())
            .max_element();
        let slack = self.slack(spread);
        let nearest = self.origin.max(b.min).min(b.max);
        let reach = self.reach + slack;
        if (nearest - self.origin).length_squared() > reach * reach {
            return false;
        }
        let centre = (b.min + b.max) * 0.5;
        let top = (centre - self.origin).dot(self.normal)
            + ((b.max - b.min) * 0.5).dot(self.normal.abs());
        // A height that is not a number may hold.
        let under = top < -(self.below + slack);
        !under
    }

    /// Whether all the corners `v` lie further below the plane than the
    /// margin (for triangles this large: see [`HalfBall::may_hold`]), the
    /// triangle then under it: in the region's own space, world or placed
    /// (heights are the world's in both).
    pub fn under(&self, v: [Vec3A; 3]) -> bool {
        let below = self.below + self.slack(self.spread(v));
        v.iter()
            .all(|&v| (v - self.origin).dot(self.normal) < -below)
    }

    /// How far the corners `v` lie from the origin along any axis.
    fn spread(&self, [a, b, c]: [Vec3A; 3]) -> f32 {
        let o = self.origin;
        (a - o)
            .abs()
            .max((b - o).abs())
            .max((c - o).abs())
            .max_element()
    }

    /// Whether the triangle `a b c` (world space) may be hit by a ray of
    /// the region: false only when it lies [under](Self::under) the
    /// plane, its plane or its box lies farther than the reach, or no ray
    /// rising as steeply as the rays do reaches its plane within the
    /// reach (each margin grown with the triangle's size); true for a
    /// needle, or a plane within the margin of the origin.
    pub fn may_reach(&self, v: [Vec3A; 3]) -> bool {
        let [a, b, c] = v;
        let slack = self.slack(self.spread(v));
        let (below, reach) = (self.below + slack, self.reach + slack);
        if v.iter()
            .all(|&v| (v - self.origin).dot(self.normal) < -below)
        {
            return false;
        }
        let o = self.origin;
        let nearest = o.max(a.min(b).min(c)).min(a.max(b).max(c));
        if (nearest - o).length_squared() > reach * reach {
            return false;
        }
        let (e1, e2) = (b - a, c - a);
        let face = e1.cross(e2);
        let area = face.length();
        // A needle's plane is not well defined, nor one that is not finite.
        if area.is_nan() || area <= 1e-5 * e1.length() * e2.length() {
            return true;
        }
        let height = (o - a).dot(face) / area;
        if height.abs() > reach {
            return false;
        }
        if height.abs() <= below {
            // Through the origin, near enough: a ray may meet it at once.
            return true;
        }
        // The face's unit normal on the origin's side: a ray meets the
        // plane only heading against it, and within the reach only if
        // steeply enough, by more than the cosine `least` allows.
        let toward = face / area * height.signum();
        let cos_b = self.normal.dot(toward).clamp(-1.0, 1.0);
        let (cos_a, sin_a) = (self.rise, (1.0 - self.rise * self.rise).max(0.0).sqrt());
        // The least cosine between `toward` and a direction within the
        // rays' cone (half angle `a` about the normal, `b` from
        // `toward`): cos(b + a), or -1 once b + a passes a half turn.
        let least = if cos_b < -cos_a {
            -1.0
        } else {
            cos_b * cos_a - (1.0 - cos_b * cos_b).max(0.0).sqrt() * sin_a
        };
        let clear = (height.abs() - below) / reach;
        let ruled_out = least - 1e-4 >= -clear;
        !ruled_out
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::{Affine3A, Quat, Vec3};

    use crate::random::uniform;
    use crate::trace::ao::{AoParams, AoTracer, Estimator, PointRays};
    use crate::trace::geometry::{Geometry, Layer, TriangleBvh};

    fn params(radius: f32, rays: u32, estimator: Estimator) -> AoParams {
        AoParams {
            radius,
            rays,
            estimator,
            ..AoParams::default()
        }
    }

    /// One layer of `tris` (world space) as a wide or refittable BVH,
    /// placed by `to_world` (its triangles given in its local space).
    fn layer(tris: &[[Vec3; 3]], to_world: Option<Affine3A>, refittable: bool) -> Layer {
        let local: Vec<[Vec3; 3]> = match to_world {
            None => tris.to_vec(),
            Some(m) => {
                let back = m.inverse();
                tris.iter()
                    .map(|t| t.map(|v| back.transform_point3(v)))
                    .collect()
            }
        };
        let geometry = Geometry {
            triangles: local,
            masks: Vec::new(),
        };
        let bvh = Arc::new(if refittable {
            TriangleBvh::refittable(geometry)
        } else {
            TriangleBvh::new(geometry)
        });
        match to_world {
            None => Layer::world(bvh),
            Some(m) => Layer::placed(bvh, m),
        }
    }

    fn every_ray_misses(id: u32, at: Vec3, normal: Vec3, tracer: &AoTracer, p: &AoParams) -> bool {
        let mut scores = vec![0.0; p.rays as usize];
        tracer.trace_point_rays(id, at, normal, p, &mut scores, |_| true);
        scores.iter().all(|&s| s == 1.0)
    }

    fn open(id: u32, at: Vec3, normal: Vec3, tracer: &AoTracer, p: &AoParams) -> bool {
        PointRays::new(id, at, normal, p).is_some_and(|r| r.surely_open(tracer))
    }

    #[test]
    fn a_point_with_nothing_in_reach_above_it_is_open_and_one_with_something_is_not() {
        let p = params(0.6, 32, Estimator::ClosestHit);
        let floor = [
            [
                Vec3::new(-5.0, 0.0, -5.0),
                Vec3::new(5.0, 0.0, -5.0),
                Vec3::new(5.0, 0.0, 5.0),
            ],
            [
                Vec3::new(-5.0, 0.0, -5.0),
                Vec3::new(5.0, 0.0, 5.0),
                Vec3::new(-5.0, 0.0, 5.0),
            ],
        ];
        let tile = |y: f32, x: f32| {
            [
                Vec3::new(x - 0.1, y, -0.1),
                Vec3::new(x + 0.1, y, -0.1),
                Vec3::new(x, y, 0.1),
            ]
        };
        let at = Vec3::ZERO;
        for (extra, want) in [
            (None, true),
            // Within reach above: may be hit.
            (Some(tile(0.3, 0.0)), false),
            // Above, but beyond the radius.
            (Some(tile(0.7, 0.0)), true),
            // Beside, beyond the radius.
            (Some(tile(0.1, 0.9)), true),
            // Under the floor, within the radius.
            (Some(tile(-0.3, 0.0)), true),
        ] {
            let mut tris = floor.to_vec();
            tris.extend(extra);
            let tracer = AoTracer::from_layers(vec![layer(&tris, None, false)]);
            assert_eq!(open(7, at, Vec3::Y, &tracer, &p), want, "{extra:?}");
            if want {
                assert!(every_ray_misses(7, at, Vec3::Y, &tracer, &p));
            }
        }
    }

    #[test]
    fn a_point_said_open_has_no_ray_that_hits() {
        // Triangles drawn about a point (its own tilted as an interpolated
        // normal leaves it, others above, below, beside and beyond the
        // radius), in world, placed, rotated and stretched layers, wide or
        // refittable, near the origin of the world and far from it: where
        // the test says open, every ray must miss.
        let (mut said_open, mut traced, mut missed_anyway) = (0, 0, 0);
        for case in 0..3000u32 {
            let u = |k: u32| uniform(11, case, k);
            let radius = [0.6, 0.01, 4.0][(u(0) * 3.0) as usize % 3];
            let estimator = if u(1) < 0.5 {
                Estimator::ClosestHit
            } else {
                Estimator::LaineKarras
            };
            let p = params(radius, [8, 16, 32][(u(2) * 3.0) as usize % 3], estimator);
            let far = [0.0, 50.0, 3e3][(u(3) * 3.0) as usize % 3];
            let at = Vec3::new(u(4) - 0.5, u(5) - 0.5, u(6) - 0.5) * far;
            let normal = Vec3::new(u(7) - 0.5, u(8) - 0.5, u(9) - 0.5)
                .try_normalize()
                .unwrap_or(Vec3::Z);
            let (t1, t2) = normal.any_orthonormal_pair();
            // Its own triangle, tilted by up to 12 degrees.
            let tilt = Quat::from_axis_angle(t1, (u(10) - 0.5) * 0.42);
            let (a1, a2) = (tilt * t1, tilt * t2);
            let size = radius * (0.05 + 2.0 * u(11));
            let mut tris = vec![[
                at - (a1 + a2) * size,
                at + a1 * size * 2.0 - a2 * size,
                at + a2 * size * 2.0,
            ]];
            for j in 0..(u(12) * 5.0) as u32 {
                let w = |k: u32| u(20 + 8 * j + k);
                // Height over the plane and distance: often near the
                // radius and near the plane.
                let h = radius * (w(0) * 2.4 - 1.0);
                let side = radius * w(1) * 1.6;
                let c = at + normal * h + (t1 * (w(2) - 0.5) + t2 * (w(3) - 0.5)) * 2.0 * side;
                let s = radius * (0.02 + 0.6 * w(4));
                tris.push([
                    c + t1 * s,
                    c + t2 * s + normal * s * (w(5) - 0.5),
                    c - (t1 + t2) * s,
                ]);
            }
            let placed = match (u(13) * 4.0) as u32 {
                0 => None,
                1 => Some(Affine3A::from_translation(Vec3::new(1.0, -2.0, 0.5) * far)),
                2 => Some(Affine3A::from_rotation_translation(
                    Quat::from_rotation_y(u(14) * 6.0) * Quat::from_rotation_x(u(15)),
                    Vec3::new(u(16), 0.0, -1.0),
                )),
                _ => Some(Affine3A::from_scale_rotation_translation(
                    Vec3::new(0.3 + u(14), 2.0, 0.5 + 3.0 * u(15)),
                    Quat::from_rotation_z(u(16) * 6.0),
                    Vec3::ZERO,
                )),
            };
            // One layer, or two (the top level's BVH, with the own
            // triangle apart).
            let refit = u(17) < 0.5;
            let layers = if u(18) < 0.5 {
                vec![layer(&tris, placed, refit)]
            } else {
                vec![
                    layer(&tris[..1], None, !refit),
                    layer(&tris[1..], placed, refit),
                    layer(&[], None, false),
                ]
            };
            let tracer = AoTracer::from_layers(layers);
            // Each case its own rays (the steepness of the lowest varies).
            let misses = every_ray_misses(case, at, normal, &tracer, &p);
            if open(case, at, normal, &tracer, &p) {
                said_open += 1;
                assert!(misses, "case {case}: said open, but a ray hits");
            } else {
                traced += 1;
                missed_anyway += usize::from(misses);
            }
        }
        // Both answers are common, and so are points traced whose rays
        // all miss (what the test cannot rule out).
        assert!(
            said_open > 500 && traced > 500 && missed_anyway > 50,
            "{said_open} {traced} {missed_anyway}"
        );
    }

    fn turned(u: &dyn Fn(u32) -> f32, k: u32) -> Quat {
        Quat::from_rotation_y(u(k) * std::f32::consts::TAU)
            * Quat::from_rotation_x(u(k + 1) * 3.0)
            * Quat::from_rotation_z(u(k + 2) * 6.0)
    }

    /// Over `cases` drawn (case, point, normal, tracer, parameters): how
    /// many the test said open while a ray hits (must be none), and how
    /// many it said open.
    fn wrongly_open(
        cases: u32,
        draw: impl Fn(u32) -> (Vec3, Vec3, AoTracer, AoParams),
    ) -> (u32, u32) {
        let (mut wrong, mut said) = (0, 0);
        for case in 0..cases {
            let (at, n, tracer, p) = draw(case);
            if open(case, at, n, &tracer, &p) {
                said += 1;
                wrong += u32::from(!every_ray_misses(case, at, n, &tracer, &p));
            }
        }
        (wrong, said)
    }

    #[test]
    fn a_ray_offset_of_nearly_nothing_keeps_the_point_traced() {
        // The point's own triangle passes within the margin of the rays'
        // origin: a ray may meet it at once.
        let (wrong, _) = wrongly_open(2000, |case| {
            let u = |k: u32| uniform(99, case, k);
            let size = [0.5f32, 5.0, 50.0][((case / 4) % 3) as usize];
            let estimator = if u(9) < 0.5 {
                Estimator::ClosestHit
            } else {
                Estimator::LaineKarras
            };
            let mut p = params(0.6, 32, estimator);
            p.bias = [0.0, 1e-6, 1e-5, 5e-5][(case % 4) as usize];
            let q = turned(&u, 20);
            let centre = Vec3::new(u(4) - 0.5, u(5) - 0.5, u(6) - 0.5) * size;
            let [a, b, c] = [
                Vec3::new(-size, 0.0, -size),
                Vec3::new(size, 0.0, -size),
                Vec3::new(0.0, 0.0, size),
            ]
            .map(|v| centre + q * v);
            let n = (b - a).cross(c - a).normalize();
            let at = a + (b - a) * (0.2 + 0.3 * u(1)) + (c - a) * (0.2 + 0.3 * u(2));
            let tracer = AoTracer::from_layers(vec![layer(&[[a, b, c]], None, u(3) < 0.5)]);
            (at, n, tracer, p)
        });
        assert_eq!(wrong, 0);
    }

    #[test]
    fn a_large_triangle_just_under_the_origin_is_kept_in() {
        // The hit test's rounding grows with the triangle's size: a plane
        // of a thousand metres a few micrometres under the rays' origin
        // can be hit.
        let (wrong, said) = wrongly_open(2000, |case| {
            let u = |k: u32| uniform(55, case, k);
            let size = [10.0f32, 100.0, 1000.0][(case % 3) as usize];
            let q = turned(&u, 20);
            let n = q * Vec3::Y;
            let at = Vec3::new(u(1) - 0.5, u(2) - 0.5, u(8) - 0.5);
            let depth = [2e-6f32, 5e-6, 2e-5, 1e-4][(case / 3 % 4) as usize];
            let plane = at + n * (1e-3 - depth);
            let t = [
                Vec3::new(-size, 0.0, -size),
                Vec3::new(size, 0.0, -size),
                Vec3::new(0.0, 0.0, size),
            ]
            .map(|v| plane + q * v);
            let tracer = AoTracer::from_layers(vec![layer(&[t], None, u(3) < 0.5)]);
            (at, n, tracer, params(0.01, 32, Estimator::ClosestHit))
        });
        assert_eq!(wrong, 0, "of {said} said open");
    }

    #[test]
    fn a_layer_far_from_its_own_origin_is_tested_with_its_own_rounding() {
        // A layer authored in large coordinates (a survey's) and moved
        // back near the world's origin: its rounding is that of its own
        // coordinates.
        let (wrong, _) = wrongly_open(2000, |case| {
            let u = |k: u32| uniform(77, case, k);
            let off = [1e3f32, 1e4, 1e5][(case % 3) as usize];
            let size = 0.5 + 2.0 * u(0);
            let q = turned(&u, 20);
            let base = Vec3::new(off, off * 0.7 + 0.123, off * 0.5);
            let [a, b, c] = [
                Vec3::new(-size, 0.0, -size),
                Vec3::new(size, 0.0, -size),
                Vec3::new(0.0, 0.0, size),
            ]
            .map(|v| base + q * v);
            let m =
                Affine3A::from_rotation_translation(turned(&u, 30), Vec3::new(u(5), u(6), u(7)))
                    * Affine3A::from_translation(-base);
            let local = a + (b - a) * (0.2 + 0.3 * u(1)) + (c - a) * (0.2 + 0.3 * u(2));
            let at = m.transform_point3(local);
            let n = m.transform_vector3((b - a).cross(c - a)).normalize();
            let bvh = Arc::new(TriangleBvh::new(Geometry {
                triangles: vec![[a, b, c]],
                masks: Vec::new(),
            }));
            let tracer =
                AoTracer::from_layers(vec![Layer::placed(bvh, m), layer(&[], None, false)]);
            let radius = [0.6, 0.05][(case / 3 % 2) as usize];
            (at, n, tracer, params(radius, 32, Estimator::ClosestHit))
        });
        assert_eq!(wrong, 0);
    }

    #[test]
    fn the_walk_down_a_bvh_finds_what_testing_every_triangle_finds() {
        use glam::Vec3A;
        // Many triangles, so that the walk goes down inner nodes of both
        // kinds of BVH; the node tests must never prune a triangle the
        // triangle test keeps.
        let mut found = 0;
        for case in 0..300u32 {
            let u = |k: u32| uniform(33, case, k);
            let count = [50u32, 500, 5000][(case % 3) as usize];
            let tris: Vec<[Vec3; 3]> = (0..count)
                .map(|j| {
                    let w = |k: u32| uniform(34 + case as u64, j, k);
                    let c = Vec3::new(w(0) - 0.5, w(1) - 0.5, w(2) - 0.5) * 20.0;
                    let s = 0.05 + 0.3 * w(3);
                    [
                        c,
                        c + Vec3::new(s, w(4) * s, 0.0),
                        c + Vec3::new(0.0, s, w(5) * s),
                    ]
                })
                .collect();
            let geometry = Geometry {
                triangles: tris.clone(),
                masks: Vec::new(),
            };
            let bvh = if u(0) < 0.5 {
                TriangleBvh::refittable(geometry)
            } else {
                TriangleBvh::new(geometry)
            };
            let o = Vec3A::new(u(1) - 0.5, u(2) - 0.5, u(3) - 0.5) * 20.0;
            let n = Vec3A::new(u(4) - 0.5, u(5) - 0.5, u(6) - 0.5).normalize();
            let region = super::HalfBall::new(o, n, 0.2 + u(7) * 2.0, u(8) * 0.5);
            let walked = bvh.any_near(
                |b| region.may_hold(b),
                |t| region.may_reach([t.v0, t.v1, t.v2]),
            );
            let every = tris.iter().any(|t| region.may_reach(t.map(Vec3A::from)));
            assert_eq!(walked, every, "case {case}");
            found += u32::from(every);
        }
        assert!(found > 50 && found < 250, "{found}");
    }
}
