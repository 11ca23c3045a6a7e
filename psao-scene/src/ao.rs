//! CPU ray-traced ambient occlusion for points (paper 3.3) with obvhs.
//!
//! Two estimators with the same expectation, `E[min(t, R) / R]` over
//! cosine-distributed directions:
//! - closest hit: trace to `R`, score `min(t, R) / R`;
//! - Laine-Karras: draw `u` uniform in `[0, 1)`, trace a first-hit
//!   (occlusion) ray of length `u R`, score 1 if it misses. Since
//!   `P(t > u R) = E[min(t, R) / R]` for uniform `u`, the mean is the same,
//!   with shorter rays that stop at the first hit.

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
use psao_codec::{SentPoint, Thresholds};
use rayon::prelude::*;

use crate::alpha::AlphaMask;
use crate::error::{SceneError, check_param};
use crate::random::{hash, uniform};

/// How far (in `t`) AO rays start behind their origin. obvhs's wide BVH
/// (CWBVH) skips every child box that a ray leaves within 1e-4 of its
/// start, whatever the ray's `tmin` (an absolute distance in obvhs 0.4,
/// `cwbvh::node::EPSILON`, not exported). At metre scale that loses
/// nothing; in a scene a few millimetres across (an AO radius of 0.6 mm)
/// it lost the occlusion of nearby surfaces, and AO came out brighter than
/// the binary BVH's by 0.044 RMSE (`tests/stability.rs`). Starting rays
/// this far back, with `tmin` at the true origin, puts every box they can
/// hit beyond that clamp and still counts hits from the origin on.
const RAY_LEAD: f32 = 2e-4;

/// The golden ratio's fractional part in 32-bit fixed point.
const GOLDEN: u32 = 0x9E37_79B9;

/// Most rays per point.
pub const MAX_RAYS: u32 = 1 << 20;

/// How a point's ray scores are added up: ray `k` goes into partial sum
/// `k % RAY_SUM_LANES`, and the partial sums are then added in order. A
/// GPU that traces one point on this many invocations (psao-gpu) adds in
/// the same order, so the two backends round alike.
pub const RAY_SUM_LANES: u32 = 8;

/// Which AO estimator to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimator {
    /// Closest-hit rays of length R, scored `min(t, R) / R`.
    ClosestHit,
    /// Occlusion rays of uniform random length in `[0, R)`, scored 0 or 1
    /// (Laine and Karras 2010).
    LaineKarras,
}

/// AO parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AoParams {
    /// Falloff radius R (the paper: 0.6 m).
    pub radius: f32,
    /// Rays per point (the prototype: 192).
    pub rays: u32,
    /// Ray origin offset along the normal, against self-intersection.
    pub bias: f32,
    /// The estimator.
    pub estimator: Estimator,
    /// Seed of the ray directions (and lengths).
    pub seed: u64,
}

impl AoParams {
    /// Checks radius (finite, > 0), bias (finite, >= 0) and rays
    /// (at most [`MAX_RAYS`]).
    pub fn validate(&self) -> Result<(), SceneError> {
        check_param(
            "radius",
            self.radius as f64,
            1e-30,
            1e30,
            "finite and positive",
        )?;
        check_param(
            "bias",
            self.bias as f64,
            0.0,
            1e30,
            "finite and not negative",
        )?;
        check_param(
            "rays",
            self.rays as f64,
            0.0,
            MAX_RAYS as f64,
            "at most 2^20",
        )
    }
}

impl Default for AoParams {
    fn default() -> Self {
        AoParams {
            radius: 0.6,
            rays: 192,
            bias: 1e-3,
            estimator: Estimator::ClosestHit,
            seed: 1,
        }
    }
}

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
        match &mut self.accel {
            Some(Accel::Binary(bvh)) => {
                for n in 0..bvh.nodes.len() {
                    let node = bvh.nodes[n];
                    if !node.is_leaf() {
                        continue;
                    }
                    let mut aabb = Aabb::empty();
                    for k in node.first_index..node.first_index + node.prim_count {
                        if let Some(&prim) = bvh.primitive_indices.get(k as usize) {
                            if let Some(t) = self.tris.get(prim as usize) {
                                aabb = aabb.union(&t.aabb());
                            }
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
    fn closest(&self, ray: Ray) -> f32 {
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

    /// Whether `ray` hits nothing.
    fn misses(&self, ray: Ray) -> bool {
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

    /// The ray from `origin` along `dir` up to `tmax`, in the layer's space
    /// (the same `t` reaches the same point), started [`RAY_LEAD`] behind
    /// `origin` with `tmin` at `origin`: its `t` runs `RAY_LEAD` ahead.
    /// `None` when the ray is not finite in the layer's space (a point near
    /// the largest f32, or a transform that takes it there): it can hit
    /// nothing there.
    fn local(&self, origin: Vec3A, dir: Vec3A, tmax: f32) -> Option<Ray> {
        let start = origin - dir * RAY_LEAD;
        let (start, dir) = match &self.to_local {
            None => (start, dir),
            Some(m) => (m.transform_point3a(start), m.transform_vector3a(dir)),
        };
        (start.is_finite() && dir.is_finite())
            .then(|| Ray::new(start, dir, RAY_LEAD, tmax + RAY_LEAD))
    }
}

/// Traces AO rays against one or more placed triangle BVHs (for example a
/// static one built once, and one per moving instance).
#[derive(Clone, Debug)]
pub struct AoTracer {
    layers: Vec<Layer>,
}

/// AO of a batch of points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AoResult {
    /// AO per point, in input order (1 = open).
    pub ao: Vec<f32>,
    /// Rays traced.
    pub rays: u64,
}

/// The points of a batch worth sending: those whose new AO, position or
/// normal passed the thresholds against what clients hold
/// ([`psao_codec::SentPoint::changed`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChangedPoints {
    /// Indices into the batch of the changed points, ascending.
    pub changed: Vec<u32>,
    /// AO of each changed point, in the order of `changed`.
    pub ao: Vec<f32>,
    /// The cells whose held words change (`SentPoint::cell` of the changed
    /// points that had a word), ascending, each once. A changed point
    /// without a word gets a cell only when it is set.
    pub cells: Vec<u32>,
    /// Rays traced.
    pub rays: u64,
}

impl ChangedPoints {
    /// Compares a traced batch with what clients hold, one record per
    /// point, on the host.
    pub fn compare(
        result: &AoResult,
        sent: &[SentPoint],
        thresholds: &Thresholds,
    ) -> Result<ChangedPoints, SceneError> {
        if sent.len() != result.ao.len() {
            return Err(SceneError::SentCount {
                points: result.ao.len(),
                sent: sent.len(),
            });
        }
        let mut out = ChangedPoints {
            rays: result.rays,
            ..ChangedPoints::default()
        };
        for (i, (s, &ao)) in sent.iter().zip(&result.ao).enumerate() {
            if s.changed(ao, thresholds) {
                out.changed.push(i as u32);
                out.ao.push(ao);
                if s.word.is_allocated() {
                    out.cells.push(s.cell);
                }
            }
        }
        out.cells.sort_unstable();
        out.cells.dedup();
        Ok(out)
    }
}

impl AoTracer {
    /// Builds one BVH over `triangles` (all solid).
    pub fn new(triangles: &[[Vec3; 3]]) -> AoTracer {
        AoTracer::from_layers(vec![Layer::world(Arc::new(TriangleBvh::new(Geometry {
            triangles: triangles.to_vec(),
            masks: Vec::new(),
        })))])
    }

    /// Traces against all of `layers` together.
    pub fn from_layers(layers: Vec<Layer>) -> AoTracer {
        AoTracer { layers }
    }

    /// Number of triangles over all layers.
    pub fn triangles(&self) -> usize {
        self.layers.iter().map(|l| l.bvh.len()).sum()
    }

    /// AO at points with unit normals; point `i` draws its random numbers
    /// as point id `i`. See [`trace_ids`](Self::trace_ids).
    pub fn trace(
        &self,
        points: &[Vec3],
        normals: &[Vec3],
        p: &AoParams,
    ) -> Result<AoResult, SceneError> {
        let ids: Vec<u32> = (0..points.len() as u32).collect();
        self.trace_ids(&ids, points, normals, p)
    }

    /// AO at points with unit normals and stable ids (a point's random
    /// numbers depend on its id, so re-tracing a subset gives each point
    /// the same rays). Rays are traced in parallel over points sorted along
    /// a Morton curve (coherent rays); the result does not depend on the
    /// thread count. A non-finite point, or one so near the largest f32
    /// that its ray origin overflows, is reported open (1).
    pub fn trace_ids(
        &self,
        ids: &[u32],
        points: &[Vec3],
        normals: &[Vec3],
        p: &AoParams,
    ) -> Result<AoResult, SceneError> {
        p.validate()?;
        if points.len() != normals.len() || points.len() != ids.len() {
            return Err(SceneError::LengthMismatch {
                points: points.len(),
                normals: normals.len().min(ids.len()),
            });
        }
        let order = morton_order(points);
        let mut sorted: Vec<(usize, f32)> = order
            .par_iter()
            .map(|&i| (i, self.point_ao(ids[i], points[i], normals[i], p)))
            .collect();
        sorted.sort_unstable_by_key(|x| x.0);
        Ok(AoResult {
            ao: sorted.into_iter().map(|x| x.1).collect(),
            rays: points.len() as u64 * p.rays as u64,
        })
    }

    /// AO at one point; `id` selects its random numbers. `p` must be
    /// valid ([`AoParams::validate`]).
    fn point_ao(&self, id: u32, point: Vec3, normal: Vec3, p: &AoParams) -> f32 {
        if self.layers.iter().all(|l| l.bvh.is_empty()) {
            return 1.0;
        }
        if p.rays == 0 || !point.is_finite() {
            return 1.0;
        }
        let n = normal.try_normalize().unwrap_or(Vec3::Z);
        let (t1, t2) = n.any_orthonormal_pair();
        let bias = ray_offset(p.bias, point);
        let origin = Vec3A::from(point + n * bias);
        if !origin.is_finite() {
            // Within a ray offset of the largest f32: nothing to trace from.
            return 1.0;
        }
        let shift = hash(p.seed as u32 ^ hash(id ^ hash((p.seed >> 32) as u32)));
        let mut sums = [0.0f32; RAY_SUM_LANES as usize];
        for k in 0..p.rays {
            let sum = &mut sums[(k % RAY_SUM_LANES) as usize];
            // Stratified in r1 (one stratum per ray), random within.
            let r1 = (k as f32 + uniform(p.seed, id, 3 * k)) / p.rays as f32;
            let r2 = uniform(p.seed, id, 3 * k + 1);
            let (s, c) = (std::f32::consts::TAU * r2).sin_cos();
            let rr = r1.sqrt();
            let dir = t1 * (rr * c) + t2 * (rr * s) + n * (1.0 - r1).max(0.0).sqrt();
            let dir = Vec3A::from(dir);
            match p.estimator {
                Estimator::ClosestHit => {
                    // Each layer's ray ends at the nearest hit so far.
                    let mut t = p.radius;
                    for l in &self.layers {
                        if let Some(ray) = l.local(origin, dir, t) {
                            t = t.min(l.bvh.closest(ray) - RAY_LEAD);
                        }
                    }
                    *sum += t / p.radius;
                }
                Estimator::LaineKarras => {
                    // Lengths from a golden-ratio sequence, rotated per
                    // point: evenly spread over [0, 1) and uncorrelated
                    // with the direction strata.
                    let u = (k.wrapping_mul(GOLDEN).wrapping_add(shift) >> 8) as f32
                        / (1u32 << 24) as f32;
                    let len = u * p.radius;
                    if self
                        .layers
                        .iter()
                        .all(|l| l.local(origin, dir, len).is_none_or(|r| l.bvh.misses(r)))
                    {
                        *sum += 1.0;
                    }
                }
            }
        }
        sums.iter().fold(0.0, |total, &s| total + s) / p.rays as f32
    }
}

/// How far along its normal a ray starts from `point`: the configured bias
/// plus a part that grows with the coordinates, so the offset stays above
/// f32 rounding far from the origin.
pub fn ray_offset(bias: f32, point: Vec3) -> f32 {
    bias + point.abs().max_element() * (1.0 / (1u32 << 21) as f32)
}

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
    let mut idx: Vec<usize> = (0..points.len()).collect();
    idx.sort_by_key(|&i| (code(points[i]), i));
    idx
}
