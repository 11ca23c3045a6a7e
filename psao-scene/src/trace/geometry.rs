//! What AO rays are traced against: triangles with optional alpha masks
//! ([`Geometry`]), a BVH over them ([`TriangleBvh`], obvhs: a wide one
//! built once, or a binary one refitted as its triangles move) and a BVH
//! placed in the world by a transform ([`Layer`]).

use std::sync::Arc;
use std::time::Duration;

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;

use super::open::HalfBall;
use crate::model::alpha::AlphaMask;
use crate::model::mesh::transformed_bounds;

/// How far (in `t`) AO rays start behind their origin. obvhs's wide BVH
/// (CWBVH) skips every child box that a ray leaves within 1e-4 of its
/// start, whatever the ray's `tmin` (an absolute distance in obvhs 0.4,
/// `cwbvh::node::EPSILON`, not exported). At metre scale that loses
/// nothing; in a scene a few millimetres across (an AO radius of 0.6 mm)
/// it lost the occlusion of nearby surfaces, and AO came out brighter than
/// the binary BVH's by 0.044 RMSE (`tests/stability.rs`). Starting rays
/// this far back, with `tmin` at the true origin, puts every box they can
/// hit beyond that clamp and still counts hits from the origin on.
pub(crate) const RAY_LEAD: f32 = 2e-4;

/// The alpha mask of one triangle: the mask and the triangle's vertex
/// indices in the mesh the mask belongs to.
pub type TriangleMask = Option<(Arc<AlphaMask>, [u32; 3])>;

/// Triangles to trace against, with optional alpha masks.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    /// Triangles.
    pub triangles: Vec<[Vec3; 3]>,
    /// Per triangle, its alpha mask (empty: every triangle is solid).
    pub masks: Vec<TriangleMask>,
}

/// The acceleration structure of a [`TriangleBvh`].
#[derive(Clone)]
enum Accel {
    /// obvhs CWBVH: fastest to trace, built once.
    Wide(CwBvh),
    /// obvhs binary BVH: traced a little slower, but refitted in place
    /// when its triangles move (skinned meshes).
    Binary(Bvh2),
}

/// A BVH over triangles (in any one space). Rays pass through alpha-mask
/// holes. [`new`](Self::new) builds a wide BVH for geometry that keeps its
/// shape; [`refittable`](Self::refittable) one whose bounds
/// [`refit`](Self::refit) follows deforming triangles without a rebuild.
#[derive(Clone)]
pub struct TriangleBvh {
    accel: Option<Accel>,
    tris: Vec<Triangle>,
    masks: Vec<TriangleMask>,
    /// The box of the triangles (`None`: no triangle).
    bounds: Option<(Vec3, Vec3)>,
}

impl std::fmt::Debug for TriangleBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TriangleBvh")
            .field("triangles", &self.tris.len())
            .field("refittable", &matches!(self.accel, Some(Accel::Binary(_))))
            .finish()
    }
}

fn to_triangles(triangles: &[[Vec3; 3]]) -> Vec<Triangle> {
    triangles
        .iter()
        .map(|t| Triangle {
            v0: t[0].into(),
            v1: t[1].into(),
            v2: t[2].into(),
        })
        .collect()
}

fn bounds_of_triangles(tris: &[Triangle]) -> Option<(Vec3, Vec3)> {
    let first = tris.first()?;
    let b = tris.iter().fold(first.aabb(), |b, t| b.union(&t.aabb()));
    Some((b.min.into(), b.max.into()))
}

fn keep_masks(masks: Vec<TriangleMask>) -> Vec<TriangleMask> {
    if masks.iter().any(|m| m.is_some()) {
        masks
    } else {
        Vec::new()
    }
}

impl TriangleBvh {
    /// Builds a wide BVH (obvhs CWBVH, "fast" preset).
    pub fn new(geometry: Geometry) -> TriangleBvh {
        TriangleBvh::build(geometry, false)
    }

    /// Builds a binary BVH that [`refit`](Self::refit) can update when the
    /// triangles move (the tree stays, its boxes follow).
    pub fn refittable(geometry: Geometry) -> TriangleBvh {
        TriangleBvh::build(geometry, true)
    }

    fn build(geometry: Geometry, refittable: bool) -> TriangleBvh {
        let tris = to_triangles(&geometry.triangles);
        let params = BvhBuildParams::fast_build();
        let accel = (!tris.is_empty()).then(|| {
            if refittable {
                Accel::Binary(build_bvh2_from_tris(
                    &tris,
                    params,
                    &mut Duration::default(),
                ))
            } else {
                Accel::Wide(build_cwbvh_from_tris(
                    &tris,
                    params,
                    &mut Duration::default(),
                ))
            }
        });
        TriangleBvh {
            accel,
            bounds: bounds_of_triangles(&tris),
            tris,
            masks: keep_masks(geometry.masks),
        }
    }

    /// Moves the triangles to `triangles` (same count and order as built)
    /// and refits the boxes of a refittable BVH; a wide BVH is rebuilt.
    /// Returns false, changing nothing, when the count differs.
    pub fn refit(&mut self, triangles: &[[Vec3; 3]]) -> bool {
        if triangles.len() != self.tris.len() {
            return false;
        }
        self.tris = to_triangles(triangles);
        self.bounds = bounds_of_triangles(&self.tris);
        match &mut self.accel {
            Some(Accel::Binary(bvh)) => {
                for n in 0..bvh.nodes.len() {
                    let node = bvh.nodes[n];
                    if !node.is_leaf() {
                        continue;
                    }
                    let mut aabb = Aabb::empty();
                    for k in node.first_index..node.first_index + node.prim_count {
                        if let Some(&prim) = bvh.primitive_indices.get(k as usize)
                            && let Some(t) = self.tris.get(prim as usize)
                        {
                            aabb = aabb.union(&t.aabb());
                        }
                    }
                    bvh.nodes[n].set_aabb(aabb);
                }
                bvh.refit_all();
            }
            Some(Accel::Wide(bvh)) => {
                *bvh = build_cwbvh_from_tris(
                    &self.tris,
                    BvhBuildParams::fast_build(),
                    &mut Duration::default(),
                );
            }
            None => {}
        }
        true
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Bytes held: the triangles, their masks and the BVH's nodes and
    /// primitive indices (allocated capacity).
    pub fn memory_bytes(&self) -> u64 {
        use std::mem::size_of;
        let accel = match &self.accel {
            None => 0,
            Some(Accel::Wide(b)) => {
                b.nodes.capacity() * size_of::<obvhs::cwbvh::node::CwBvhNode>()
                    + b.primitive_indices.capacity() * 4
            }
            Some(Accel::Binary(b)) => {
                b.nodes.capacity() * size_of::<obvhs::bvh2::node::Bvh2Node>()
                    + b.primitive_indices.capacity() * 4
            }
        };
        (self.tris.capacity() * size_of::<Triangle>()
            + self.masks.capacity() * size_of::<TriangleMask>()
            + accel) as u64
    }

    /// The box of the triangles in their own space (`None`: no triangle).
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }

    /// Whether it holds no triangle.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Distance to triangle `prim` along `r`, or infinity on a miss or a
    /// hit in a hole.
    fn hit(&self, r: &Ray, prim: u32) -> f32 {
        let tri = &self.tris[prim as usize];
        let t = tri.intersect(r);
        let Some(Some((mask, v))) = self.masks.get(prim as usize) else {
            return t;
        };
        if !t.is_finite() {
            return t;
        }
        let p = Vec3::from(r.origin + r.direction * t);
        let (a, b, c) = (Vec3::from(tri.v0), Vec3::from(tri.v1), Vec3::from(tri.v2));
        if mask.solid(*v, barycentric(p, a, b, c)) {
            t
        } else {
            f32::INFINITY
        }
    }

    /// The nearest hit along `ray` (`ray.tmax` or more: none).
    pub(super) fn closest(&self, ray: Ray) -> f32 {
        let mut hit = RayHit::none();
        let found = match &self.accel {
            None => false,
            Some(Accel::Wide(bvh)) => bvh.ray_traverse(ray, &mut hit, |r, id| {
                self.hit(r, bvh.primitive_indices[id])
            }),
            Some(Accel::Binary(bvh)) => bvh.ray_traverse(ray, &mut hit, |r, id| {
                self.hit(r, bvh.primitive_indices[id])
            }),
        };
        if found { hit.t } else { f32::INFINITY }
    }

    /// The nearest hit along `ray`: the triangle's index (in build order)
    /// and the distance; `None` on a miss.
    pub fn closest_triangle(&self, ray: Ray) -> Option<(u32, f32)> {
        let mut hit = RayHit::none();
        let (found, order) = match &self.accel {
            None => return None,
            Some(Accel::Wide(bvh)) => (
                bvh.ray_traverse(ray, &mut hit, |r, id| {
                    self.hit(r, bvh.primitive_indices[id])
                }),
                &bvh.primitive_indices,
            ),
            Some(Accel::Binary(bvh)) => (
                bvh.ray_traverse(ray, &mut hit, |r, id| {
                    self.hit(r, bvh.primitive_indices[id])
                }),
                &bvh.primitive_indices,
            ),
        };
        let prim = *order.get(hit.primitive_id as usize)?;
        found.then_some((prim, hit.t))
    }

    /// Whether `near` holds for any triangle in a leaf whose box (in the
    /// BVH's space) `may_hold`: the BVH is walked down the nodes whose
    /// box `may_hold`, and the triangles of such leaves passed in turn
    /// until one holds. True as well when the walk runs out of room (a
    /// BVH deeper than any obvhs builds): the caller must then assume the
    /// worst.
    pub(super) fn any_near(
        &self,
        may_hold: impl Fn(&Aabb) -> bool,
        mut near: impl FnMut(&Triangle) -> bool,
    ) -> bool {
        let mut test = |indices: &[u32], first: u32, count: u32| {
            (first..first.saturating_add(count)).any(|k| {
                indices
                    .get(k as usize)
                    .and_then(|&p| self.tris.get(p as usize))
                    .is_some_and(&mut near)
            })
        };
        let mut stack = NodeStack::default();
        match &self.accel {
            None => false,
            Some(Accel::Binary(bvh)) => {
                let Some(root) = bvh.nodes.first() else {
                    return false;
                };
                if root.is_leaf() {
                    return may_hold(root.aabb())
                        && test(&bvh.primitive_indices, root.first_index, root.prim_count);
                }
                stack.push(root.first_index);
                while let Some(first) = stack.pop() {
                    for n in [first, first.saturating_add(1)] {
                        let Some(node) = bvh.nodes.get(n as usize) else {
                            continue;
                        };
                        if !may_hold(node.aabb()) {
                            continue;
                        }
                        if node.is_leaf() {
                            if test(&bvh.primitive_indices, node.first_index, node.prim_count) {
                                return true;
                            }
                        } else if !stack.push(node.first_index) {
                            return true;
                        }
                    }
                }
                false
            }
            Some(Accel::Wide(bvh)) => {
                // Node 0 is the root; a child's box is rounded outward.
                stack.push(0);
                while let Some(n) = stack.pop() {
                    let Some(node) = bvh.nodes.get(n as usize) else {
                        continue;
                    };
                    for child in 0..obvhs::cwbvh::BRANCHING {
                        if node.is_child_empty(child) || !may_hold(&node.child_aabb(child)) {
                            continue;
                        }
                        if !node.is_leaf(child) {
                            if !stack.push(node.child_node_index(child)) {
                                return true;
                            }
                        } else {
                            let (first, count) = node.child_primitives(child);
                            if test(&bvh.primitive_indices, first, count) {
                                return true;
                            }
                        }
                    }
                }
                false
            }
        }
    }

    /// Whether `ray` hits nothing.
    pub(super) fn misses(&self, ray: Ray) -> bool {
        match &self.accel {
            None => true,
            Some(Accel::Wide(bvh)) => {
                bvh.ray_traverse_miss(ray, |r, id| self.hit(r, bvh.primitive_indices[id]))
            }
            Some(Accel::Binary(bvh)) => {
                bvh.ray_traverse_miss(ray, |r, id| self.hit(r, bvh.primitive_indices[id]))
            }
        }
    }
}

/// Nodes still to visit in [`TriangleBvh::any_near`], on the stack of
/// the thread: room for a wide BVH's eight children at each of 32 levels
/// (obvhs builds none deeper), and more.
struct NodeStack {
    nodes: [u32; 320],
    len: usize,
}

impl Default for NodeStack {
    fn default() -> Self {
        NodeStack {
            nodes: [0; 320],
            len: 0,
        }
    }
}

impl NodeStack {
    /// Pushes `n`; false, pushing nothing, when full.
    fn push(&mut self, n: u32) -> bool {
        let Some(slot) = self.nodes.get_mut(self.len) else {
            return false;
        };
        *slot = n;
        self.len += 1;
        true
    }

    fn pop(&mut self) -> Option<u32> {
        self.len = self.len.checked_sub(1)?;
        self.nodes.get(self.len).copied()
    }
}

/// Barycentric weights of `p` (on the plane of `a b c`): how a hit on a
/// triangle interpolates its vertices' attributes.
pub fn barycentric(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> [f32; 3] {
    let (e0, e1, ep) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
    let (d20, d21) = (ep.dot(e0), ep.dot(e1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() <= f32::MIN_POSITIVE {
        return [1.0, 0.0, 0.0];
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    [1.0 - v - w, v, w]
}

/// One BVH placed in the world: its triangles are in a local space that
/// `to_world` maps to world space (an instance's own BVH, moved by its
/// transform rather than rebuilt).
#[derive(Clone, Debug)]
pub struct Layer {
    bvh: Arc<TriangleBvh>,
    to_world: Option<Affine3A>,
    /// World-to-local, cached.
    to_local: Option<Affine3A>,
}

impl Layer {
    /// A BVH in world space.
    pub fn world(bvh: Arc<TriangleBvh>) -> Layer {
        Layer {
            bvh,
            to_world: None,
            to_local: None,
        }
    }

    /// A BVH in a local space placed by `to_world` (which must be
    /// invertible).
    pub fn placed(bvh: Arc<TriangleBvh>, to_world: Affine3A) -> Layer {
        Layer {
            bvh,
            to_world: Some(to_world),
            to_local: Some(to_world.inverse()),
        }
    }

    /// The BVH.
    pub fn bvh(&self) -> &Arc<TriangleBvh> {
        &self.bvh
    }

    /// Local-to-world transform (`None`: the BVH is in world space).
    pub fn to_world(&self) -> Option<Affine3A> {
        self.to_world
    }

    /// The box of the layer's triangles in world space (`None`: no
    /// triangle, or a box that is not finite).
    pub fn world_bounds(&self) -> Option<(Vec3, Vec3)> {
        let b = self.bvh.bounds()?;
        let (lo, hi) = match &self.to_world {
            None => b,
            Some(m) => transformed_bounds(m, b),
        };
        (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
    }

    /// Whether any of the layer's triangles may reach `region` (see
    /// [`HalfBall`]): walked in the layer's space down the boxes that may
    /// meet it, each triangle then tested with its corners in world space.
    pub(super) fn may_reach(&self, region: &HalfBall) -> bool {
        let (local, world) = match (&self.to_world, &self.to_local) {
            (Some(w), Some(l)) => {
                // The layer's own rounding, allowed in world space too.
                let (local, extra) = region.placed(w, l);
                (local, region.widened(extra))
            }
            _ => (*region, *region),
        };
        self.bvh.any_near(
            |b| local.may_hold(b),
            |t| {
                let corners = [t.v0, t.v1, t.v2];
                match &self.to_world {
                    None => world.may_reach(corners),
                    // Most triangles near a point lie under its plane:
                    // ruled out before their corners are moved.
                    Some(m) => {
                        !local.under(corners)
                            && world.may_reach(corners.map(|v| m.transform_point3a(v)))
                    }
                }
            },
        )
    }

    /// The world ray `world` in the layer's space: the same `t` reaches
    /// the same point, `tmin` and `tmax` unchanged. `None` when it is not
    /// finite there (a point near the largest f32, or a transform that
    /// takes it there): it can hit nothing there.
    pub(super) fn local_ray(&self, world: &Ray) -> Option<Ray> {
        let (start, dir) = match &self.to_local {
            None => (world.origin, world.direction),
            Some(m) => (
                m.transform_point3a(world.origin),
                m.transform_vector3a(world.direction),
            ),
        };
        (start.is_finite() && dir.is_finite()).then(|| Ray::new(start, dir, world.tmin, world.tmax))
    }
}

/// The world ray of an AO ray from `origin` along `dir` up to `tmax`,
/// started [`RAY_LEAD`] behind `origin` with `tmin` at `origin`: its `t`
/// runs `RAY_LEAD` ahead. `None` when its start is not finite.
pub(super) fn lead_ray(origin: Vec3A, dir: Vec3A, tmax: f32) -> Option<Ray> {
    let start = origin - dir * RAY_LEAD;
    start
        .is_finite()
        .then(|| Ray::new(start, dir, RAY_LEAD, tmax + RAY_LEAD))
}
