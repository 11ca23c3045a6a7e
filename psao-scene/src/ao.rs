//! CPU ray-traced ambient occlusion for points (paper 3.3) with obvhs.
//!
//! Two estimators with the same expectation, `E[min(t, R) / R]` over
//! cosine-distributed directions:
//! - closest hit: trace to `R`, score `min(t, R) / R`;
//! - Laine-Karras: draw `u` uniform in `[0, 1)`, trace a first-hit
//!   (occlusion) ray of length `u R`, score 1 if it misses. Since
//!   `P(t > u R) = E[min(t, R) / R]` for uniform `u`, the mean is the same,
//!   with shorter rays that stop at the first hit.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use rayon::prelude::*;

use crate::error::{SceneError, check_param};
use crate::random::{hash, uniform};

/// The golden ratio's fractional part in 32-bit fixed point.
const GOLDEN: u32 = 0x9E37_79B9;

/// Most rays per point.
pub const MAX_RAYS: u32 = 1 << 20;

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

/// A BVH over world-space triangles, ready to trace AO rays.
pub struct AoTracer {
    bvh: Option<CwBvh>,
    tris: Vec<Triangle>,
}

impl std::fmt::Debug for AoTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AoTracer")
            .field("triangles", &self.tris.len())
            .finish()
    }
}

/// AO of a batch of points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AoResult {
    /// AO per point, in input order (1 = open).
    pub ao: Vec<f32>,
    /// Rays traced.
    pub rays: u64,
}

impl AoTracer {
    /// Builds the BVH (obvhs CWBVH, "fast" preset).
    pub fn new(triangles: &[[Vec3; 3]]) -> AoTracer {
        let tris: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle {
                v0: t[0].into(),
                v1: t[1].into(),
                v2: t[2].into(),
            })
            .collect();
        let bvh = (!tris.is_empty()).then(|| {
            build_cwbvh_from_tris(
                &tris,
                BvhBuildParams::fast_build(),
                &mut Duration::default(),
            )
        });
        AoTracer { bvh, tris }
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
    /// thread count. A non-finite point is reported open (1).
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
        let Some(bvh) = &self.bvh else { return 1.0 };
        if p.rays == 0 || !point.is_finite() {
            return 1.0;
        }
        let n = normal.try_normalize().unwrap_or(Vec3::Z);
        let (t1, t2) = n.any_orthonormal_pair();
        let bias = ray_offset(p.bias, point);
        let origin = Vec3A::from(point + n * bias);
        let shift = hash(p.seed as u32 ^ hash(id ^ hash((p.seed >> 32) as u32)));
        let mut sum = 0.0f32;
        for k in 0..p.rays {
            // Stratified in r1 (one stratum per ray), random within.
            let r1 = (k as f32 + uniform(p.seed, id, 3 * k)) / p.rays as f32;
            let r2 = uniform(p.seed, id, 3 * k + 1);
            let (s, c) = (std::f32::consts::TAU * r2).sin_cos();
            let rr = r1.sqrt();
            let dir = t1 * (rr * c) + t2 * (rr * s) + n * (1.0 - r1).max(0.0).sqrt();
            let dir = Vec3A::from(dir);
            match p.estimator {
                Estimator::ClosestHit => {
                    let ray = Ray::new(origin, dir, 0.0, p.radius);
                    let mut hit = RayHit::none();
                    let t = if bvh.ray_traverse(ray, &mut hit, |r, id| {
                        self.tris[bvh.primitive_indices[id] as usize].intersect(r)
                    }) {
                        hit.t.min(p.radius)
                    } else {
                        p.radius
                    };
                    sum += t / p.radius;
                }
                Estimator::LaineKarras => {
                    // Lengths from a golden-ratio sequence, rotated per
                    // point: evenly spread over [0, 1) and uncorrelated
                    // with the direction strata.
                    let u = (k.wrapping_mul(GOLDEN).wrapping_add(shift) >> 8) as f32
                        / (1u32 << 24) as f32;
                    let len = u * p.radius;
                    let ray = Ray::new(origin, dir, 0.0, len);
                    if bvh.ray_traverse_miss(ray, |r, id| {
                        self.tris[bvh.primitive_indices[id] as usize].intersect(r)
                    }) {
                        sum += 1.0;
                    }
                }
            }
        }
        sum / p.rays as f32
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
