//! The top level over a tracer's layers: their world boxes in one binary
//! BVH (obvhs), so that an AO ray visits only the layers whose box it
//! crosses instead of every moving instance in turn. Built with the
//! tracer, so once per tick in the pipeline; a few hundred boxes take
//! microseconds.
//!
//! A ray's closest hit (and whether it misses) is the same as over every
//! layer in turn: a layer whose box the ray does not cross holds no
//! triangle the ray can hit (the boxes are padded against rounding in the
//! slab test), and the nearest hit over the layers visited is the nearest
//! over all.

use std::time::Duration;

use glam::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2;
use obvhs::ray::{Ray, RayHit};

use super::geometry::{Layer, lead_ray};
use super::open::HalfBall;

/// Fewest boxed layers worth a top-level BVH; fewer are tested in turn.
const MIN_BOXED: usize = 2;

/// Which layers a ray is tested against, and how.
#[derive(Clone, Default)]
pub(super) struct TopLevel {
    /// The BVH over the boxes of `boxed`.
    bvh: Option<Bvh2>,
    /// Per BVH primitive, its layer.
    boxed: Vec<u32>,
    /// Layers every ray is tested against (no finite box, or too few
    /// layers for a BVH).
    direct: Vec<u32>,
}

impl std::fmt::Debug for TopLevel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TopLevel")
            .field("boxed", &self.boxed.len())
            .field("direct", &self.direct.len())
            .finish()
    }
}

/// `(lo, hi)` grown by a little more than f32 rounding can move a slab
/// test at that size and distance from the origin.
fn padded((lo, hi): (glam::Vec3, glam::Vec3)) -> Aabb {
    let size = (hi - lo).max_element();
    let far = lo.abs().max(hi.abs()).max_element();
    let pad = size * 1e-5 + far * 1e-6 + f32::MIN_POSITIVE;
    Aabb::new(
        Vec3A::from(lo) - Vec3A::splat(pad),
        Vec3A::from(hi) + Vec3A::splat(pad),
    )
}

impl TopLevel {
    /// The top level over `layers` (layers without triangles are left out).
    pub(super) fn new(layers: &[Layer]) -> TopLevel {
        let mut top = TopLevel::default();
        let mut boxes = Vec::new();
        for (i, l) in layers.iter().enumerate() {
            if l.bvh().is_empty() {
                continue;
            }
            match l.world_bounds() {
                Some(b) => {
                    boxes.push(padded(b));
                    top.boxed.push(i as u32);
                }
                None => top.direct.push(i as u32),
            }
        }
        if boxes.len() < MIN_BOXED {
            top.direct.append(&mut top.boxed);
            top.direct.sort_unstable();
            return top;
        }
        top.bvh = Some(build_bvh2(
            &boxes,
            BvhBuildParams::fast_build(),
            &mut Duration::default(),
        ));
        top
    }

    /// Whether no layer holds a triangle.
    pub(super) fn is_empty(&self) -> bool {
        self.direct.is_empty() && self.boxed.is_empty()
    }

    /// The nearest hit of the AO ray from `origin` along `dir` up to
    /// `tmax` over all of `layers`, in the lead ray's `t` (so `RAY_LEAD`
    /// beyond the hit's distance from `origin`); `None` on a miss.
    pub(super) fn closest(
        &self,
        layers: &[Layer],
        origin: Vec3A,
        dir: Vec3A,
        tmax: f32,
    ) -> Option<f32> {
        let mut world = lead_ray(origin, dir, tmax)?;
        let mut best = f32::INFINITY;
        for &i in &self.direct {
            let l = &layers[i as usize];
            if let Some(r) = l.local_ray(&world) {
                let t = l.bvh().closest(r);
                if t < world.tmax {
                    best = t;
                    world.tmax = t;
                }
            }
        }
        if let Some(bvh) = &self.bvh {
            let mut hit = RayHit::none();
            let found = bvh.ray_traverse(world, &mut hit, |r: &Ray, id| {
                let l = &layers[self.boxed[bvh.primitive_indices[id] as usize] as usize];
                l.local_ray(r)
                    .map_or(f32::INFINITY, |local| l.bvh().closest(local))
            });
            if found {
                best = best.min(hit.t);
            }
        }
        best.is_finite().then_some(best)
    }

    /// Whether the AO ray from `origin` along `dir` up to `tmax` misses
    /// every one of `layers`.
    pub(super) fn misses(&self, layers: &[Layer], origin: Vec3A, dir: Vec3A, tmax: f32) -> bool {
        let Some(world) = lead_ray(origin, dir, tmax) else {
            return true;
        };
        let misses_layer =
            |l: &Layer, r: &Ray| l.local_ray(r).is_none_or(|local| l.bvh().misses(local));
        if !self
            .direct
            .iter()
            .all(|&i| misses_layer(&layers[i as usize], &world))
        {
            return false;
        }
        let Some(bvh) = &self.bvh else {
            return true;
        };
        bvh.ray_traverse_miss(world, |r: &Ray, id| {
            let l = &layers[self.boxed[bvh.primitive_indices[id] as usize] as usize];
            if misses_layer(l, r) {
                f32::INFINITY
            } else {
                f32::NEG_INFINITY
            }
        })
    }

    /// Whether any triangle of `layers` may be hit by a ray of `region`
    /// ([`Layer::may_reach`]), searched in the layers whose box meets the
    /// region's.
    pub(super) fn may_reach(&self, layers: &[Layer], region: &HalfBall) -> bool {
        let bounds = region.bounds();
        let cube = Aabb::new(Vec3A::from(bounds.0), Vec3A::from(bounds.1));
        let direct = |&i: &u32| {
            let l = &layers[i as usize];
            // A layer whose box is not finite is searched.
            let apart = l
                .world_bounds()
                .is_some_and(|b| !padded(b).intersect_aabb(&cube));
            !apart && l.may_reach(region)
        };
        if self.direct.iter().any(direct) {
            return true;
        }
        let Some(bvh) = &self.bvh else {
            return false;
        };
        let mut found = false;
        bvh.aabb_traverse(cube, |bvh, n| {
            let node = &bvh.nodes[n as usize];
            found = (node.first_index..node.first_index + node.prim_count).any(|k| {
                bvh.primitive_indices
                    .get(k as usize)
                    .and_then(|&p| self.boxed.get(p as usize))
                    // Its (padded) box meets the region's: searched.
                    .is_some_and(|&i| layers[i as usize].may_reach(region))
            });
            !found
        });
        found
    }

    /// Layers a ray is tested against without the BVH, and layers in it.
    pub(super) fn counts(&self) -> (usize, usize) {
        (self.direct.len(), self.boxed.len())
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::{Affine3A, Quat, Vec3};

    use super::*;
    use crate::model::mesh::Mesh;
    use crate::random::uniform;
    use crate::trace::geometry::{Geometry, TriangleBvh};

    fn bvh(mesh: &Mesh, refittable: bool) -> Arc<TriangleBvh> {
        let g = Geometry {
            triangles: (0..mesh.triangle_count())
                .map(|t| mesh.triangle(t))
                .collect(),
            masks: Vec::new(),
        };
        Arc::new(if refittable {
            TriangleBvh::refittable(g)
        } else {
            TriangleBvh::new(g)
        })
    }

    /// A floor in world space and 60 boxes placed by rotations, scales
    /// (one mirrored, one flat) and translations, some overlapping.
    fn layers() -> Vec<Layer> {
        let floor = Mesh::quad(Vec3::new(-5.0, 0.0, -5.0), Vec3::Z * 10.0, Vec3::X * 10.0);
        let cube = bvh(&Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), false);
        let skinned = bvh(&Mesh::cuboid(Vec3::splat(-0.3), Vec3::splat(0.3)), true);
        let mut out = vec![Layer::world(bvh(&floor, false))];
        for k in 0..60u32 {
            let u = |j: u32| uniform(11, k, j);
            let at = Vec3::new(u(0) * 8.0 - 4.0, u(1) * 2.0, u(2) * 8.0 - 4.0);
            let rot = Quat::from_axis_angle(
                Vec3::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5).normalize_or(Vec3::Y),
                u(6) * 6.0,
            );
            let mut scale = Vec3::splat(0.2 + u(7));
            if k == 7 {
                scale.x = -scale.x;
            }
            if k == 9 {
                scale.y = 1e-3;
            }
            let t = Affine3A::from_scale_rotation_translation(scale, rot, at);
            let b = if k % 5 == 0 { &skinned } else { &cube };
            out.push(Layer::placed(b.clone(), t));
        }
        out
    }

    #[test]
    fn the_top_level_finds_the_same_hits_as_every_layer_in_turn() {
        let layers = layers();
        let top = TopLevel::new(&layers);
        assert_eq!(top.counts(), (0, 61));
        let flat = TopLevel {
            bvh: None,
            boxed: Vec::new(),
            direct: (0..layers.len() as u32).collect(),
        };
        let (mut hits, mut misses) = (0, 0);
        for k in 0..20_000u32 {
            let u = |j: u32| uniform(5, k, j);
            let origin = Vec3A::new(u(0) * 10.0 - 5.0, u(1) * 2.5, u(2) * 10.0 - 5.0);
            let dir = Vec3A::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5).normalize_or(Vec3A::Y);
            let tmax = u(6) * 3.0;
            let a = top.closest(&layers, origin, dir, tmax);
            let b = flat.closest(&layers, origin, dir, tmax);
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "ray {k}");
            let m = top.misses(&layers, origin, dir, tmax);
            assert_eq!(m, flat.misses(&layers, origin, dir, tmax), "ray {k}");
            assert_eq!(m, a.is_none(), "ray {k}");
            if a.is_some() { hits += 1 } else { misses += 1 }
        }
        // Both outcomes are well represented.
        assert!(
            hits > 2_000 && misses > 2_000,
            "{hits} hits, {misses} misses"
        );
    }

    #[test]
    fn few_or_empty_layers_are_tested_in_turn() {
        let empty = Arc::new(TriangleBvh::new(Geometry::default()));
        let cube = bvh(&Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), false);
        let layers = [Layer::world(empty.clone()), Layer::world(cube)];
        let top = TopLevel::new(&layers);
        assert_eq!(top.counts(), (1, 0));
        assert!(TopLevel::new(&[Layer::world(empty)]).is_empty());
        let (inside, out) = (Vec3A::ZERO, Vec3A::new(1.0, 0.1, 0.2).normalize());
        assert!(top.closest(&layers, inside, out, 1.0).is_some());
        assert!(!top.misses(&layers, inside, out, 1.0));
        // A ray that starts outside the f32 range hits nothing.
        let far = Vec3A::splat(f32::INFINITY);
        assert!(top.misses(&layers, far, out, 1.0));
        assert!(top.closest(&layers, far, out, 1.0).is_none());
    }
}
