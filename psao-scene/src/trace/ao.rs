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

use glam::{Vec3, Vec3A};
use psao_codec::{SentPoint, Thresholds};
use rayon::prelude::*;

use super::geometry::{Geometry, Layer, RAY_LEAD, TriangleBvh};
use super::open::HalfBall;
use super::top::TopLevel;
use crate::error::{SceneError, check_param};
use crate::morton::morton_order;
use crate::random::{hash, uniform};

/// The golden ratio's fractional part in 32-bit fixed point: the step of a
/// point's ray azimuths (with one stratum of elevation per ray, a
/// Fibonacci lattice).
const GOLDEN: u32 = 0x9E37_79B9;

/// The square root of 2's fractional part in 32-bit fixed point: the step
/// of a point's Laine-Karras ray lengths (another irrational than the
/// azimuths', so that lengths and azimuths do not run in step).
const SQRT2: u32 = 0x6A09_E667;

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

/// Traces AO rays against one or more placed triangle BVHs (for example a
/// static one built once, and one per moving instance).
#[derive(Clone, Debug)]
pub struct AoTracer {
    layers: Vec<Layer>,
    /// The layers' world boxes in a BVH ([`TopLevel`]).
    top: TopLevel,
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
        ChangedPoints::compare_each(result, sent, |_| *thresholds)
    }

    /// [`compare`](Self::compare) with the thresholds of each point of the
    /// batch by its index.
    pub fn compare_each(
        result: &AoResult,
        sent: &[SentPoint],
        thresholds: impl Fn(usize) -> Thresholds,
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
            if s.changed(ao, &thresholds(i)) {
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

    /// Traces against all of `layers` together, through a BVH over their
    /// world boxes: a ray visits only the layers whose box it crosses.
    pub fn from_layers(layers: Vec<Layer>) -> AoTracer {
        let top = TopLevel::new(&layers);
        AoTracer { layers, top }
    }

    /// Layers with triangles: (tested by every ray, in the top-level BVH).
    pub fn layer_counts(&self) -> (usize, usize) {
        self.top.counts()
    }

    /// Number of triangles over all layers.
    pub fn triangles(&self) -> usize {
        self.layers.iter().map(|l| l.bvh().len()).sum()
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
    pub(crate) fn point_ao(&self, id: u32, point: Vec3, normal: Vec3, p: &AoParams) -> f32 {
        self.ao_of_rays(self.point_rays(id, point, normal, p).as_ref(), p)
    }

    /// AO at a point from its rays as [`point_rays`](Self::point_rays)
    /// gives them (`None`: open), as [`point_ao`](Self::point_ao) adds
    /// them up.
    pub(crate) fn ao_of_rays(&self, rays: Option<&PointRays>, p: &AoParams) -> f32 {
        let Some(rays) = rays else {
            return 1.0;
        };
        let mut sums = [0.0f32; RAY_SUM_LANES as usize];
        for k in 0..p.rays {
            sums[(k % RAY_SUM_LANES) as usize] += rays.score(self, k);
        }
        sums.iter().fold(0.0, |total, &s| total + s) / p.rays as f32
    }

    /// The rays of a point to score against this tracer (`None`: every
    /// ray scores 1, as there is nothing to trace from or nothing to
    /// hit).
    pub(crate) fn point_rays(
        &self,
        id: u32,
        point: Vec3,
        normal: Vec3,
        p: &AoParams,
    ) -> Option<PointRays> {
        PointRays::new(id, point, normal, p).filter(|_| self.can_hit())
    }

    /// Whether it holds anything a ray can hit.
    pub(crate) fn can_hit(&self) -> bool {
        !self.top.is_empty()
    }

    /// Each ray's score at one point (`scores[k]` for ray `k`, the terms
    /// [`ao_of_scores`] adds up to the point's AO), traced only for the
    /// rays `k` with `trace(k)`; the others are left as they are. Returns
    /// the rays traced. A point with no rays to trace from (see
    /// [`PointRays::new`]) scores 1 on every ray; so does every ray
    /// against an empty tracer. `p` must be valid and `scores` hold
    /// `p.rays` values.
    pub fn trace_point_rays(
        &self,
        id: u32,
        point: Vec3,
        normal: Vec3,
        p: &AoParams,
        scores: &mut [f32],
        trace: impl Fn(u32) -> bool,
    ) -> u64 {
        let rays = self.point_rays(id, point, normal, p);
        let mut traced = 0;
        for (k, s) in (0..p.rays).zip(scores.iter_mut()) {
            if trace(k) {
                *s = rays.as_ref().map_or(1.0, |r| r.score(self, k));
                traced += 1;
            }
        }
        traced
    }
}

/// A point's AO from its rays' scores: the partial sums of
/// [`RAY_SUM_LANES`] lanes added in order, divided by the ray count,
/// exactly as [`AoTracer::trace_ids`] adds them (so scores kept from one
/// trace and partly re-traced give the same bits as a full trace).
pub fn ao_of_scores(scores: &[f32]) -> f32 {
    if scores.is_empty() {
        return 1.0;
    }
    let mut sums = [0.0f32; RAY_SUM_LANES as usize];
    for (k, &s) in scores.iter().enumerate() {
        sums[k % RAY_SUM_LANES as usize] += s;
    }
    sums.iter().fold(0.0, |total, &s| total + s) / scores.len() as f32
}

/// The rays of one point, in their fixed order: ray `k`'s direction and
/// length depend on the point's id, normal and the parameters alone, so
/// the same point traces the same rays whenever it is traced.
pub struct PointRays {
    origin: Vec3A,
    n: Vec3,
    t1: Vec3,
    t2: Vec3,
    id: u32,
    shift: u32,
    azimuth: u32,
    p: AoParams,
}

impl PointRays {
    /// The rays of point `id` at `point` with `normal` (normalized here;
    /// no direction gives +Z). `None` when there is nothing to trace from:
    /// no rays, a non-finite point, or one within a ray offset of the
    /// largest f32 (its AO is 1).
    pub fn new(id: u32, point: Vec3, normal: Vec3, p: &AoParams) -> Option<PointRays> {
        if p.rays == 0 || !point.is_finite() {
            return None;
        }
        let n = normal.try_normalize().unwrap_or(Vec3::Z);
        let (t1, t2) = n.any_orthonormal_pair();
        let bias = ray_offset(p.bias, point);
        let origin = Vec3A::from(point + n * bias);
        if !origin.is_finite() {
            return None;
        }
        let shift = hash(p.seed as u32 ^ hash(id ^ hash((p.seed >> 32) as u32)));
        Some(PointRays {
            origin,
            n,
            t1,
            t2,
            id,
            shift,
            azimuth: hash(shift),
            p: *p,
        })
    }

    /// How many rays the point has.
    pub fn count(&self) -> u32 {
        self.p.rays
    }

    /// Where every ray starts.
    pub fn origin(&self) -> Vec3A {
        self.origin
    }

    /// The unit normal the rays' hemisphere is about.
    pub fn normal(&self) -> Vec3A {
        Vec3A::from(self.n)
    }

    /// Ray `k`'s unit direction and the length it is traced to (the
    /// radius for closest-hit rays, `u R` for Laine-Karras ones).
    pub fn ray(&self, k: u32) -> (Vec3A, f32) {
        let p = &self.p;
        // A jittered Fibonacci lattice on the unit square (cosine-mapped):
        // r1 has one stratum per ray, random within; the azimuth r2 steps
        // by the golden ratio from an offset drawn per point, so the rays
        // of any run of k spread evenly around the normal too. Drawing r2
        // at random per ray left clumps and gaps in azimuth, and their
        // noise (BENCHMARKS.md, issue 15, the ray lattice).
        // `rays_near` and `least_rise` rely on ray k's r1 (its squared
        // sine of elevation) lying in the stratum [k, k + 1) / rays: a
        // change of pattern must change them too.
        let r1 = self.r1(k);
        let r2 =
            (k.wrapping_mul(GOLDEN).wrapping_add(self.azimuth) >> 8) as f32 / (1u32 << 24) as f32;
        let (s, c) = (std::f32::consts::TAU * r2).sin_cos();
        let rr = r1.sqrt();
        let dir = self.t1 * (rr * c) + self.t2 * (rr * s) + self.n * (1.0 - r1).max(0.0).sqrt();
        let len = match p.estimator {
            Estimator::ClosestHit => p.radius,
            // Lengths from a sqrt(2) sequence, rotated per point: evenly
            // spread over [0, 1) and out of step with the direction
            // lattice.
            Estimator::LaineKarras => {
                let u = (k.wrapping_mul(SQRT2).wrapping_add(self.shift) >> 8) as f32
                    / (1u32 << 24) as f32;
                u * p.radius
            }
        };
        (Vec3A::from(dir), len)
    }

    /// A run of `k` holding every ray whose direction may lie within
    /// `half_angle` (radians) of the unit `axis`, found without drawing
    /// one: ray `k`'s squared sine of elevation from the normal lies in
    /// its own stratum `[k, k + 1) / rays`, and a direction within
    /// `half_angle` of `axis` has an elevation within `half_angle` of
    /// the axis's. The run is a little wider than that (a margin for
    /// rounding), so a ray outside it cannot point within `half_angle`.
    pub fn rays_near(&self, axis: Vec3A, half_angle: f32) -> std::ops::Range<u32> {
        use std::f32::consts::FRAC_PI_2;
        let rays = self.p.rays;
        if half_angle.is_nan() || !axis.is_finite() {
            return 0..rays;
        }
        // The rounding margin, in radians (far above f32's rounding of
        // unit vectors and of the angles here).
        const MARGIN: f32 = 1e-3;
        let elevation = Vec3A::from(self.n).dot(axis).clamp(-1.0, 1.0).acos();
        let low = (elevation - half_angle - MARGIN).max(0.0);
        if low > FRAC_PI_2 {
            // The whole cone lies below the tangent plane.
            return 0..0;
        }
        let high = (elevation + half_angle + MARGIN).min(FRAC_PI_2);
        let stratum = |a: f32| a.sin().powi(2) * rays as f32;
        // One stratum more on each side, for the rounding of `stratum`.
        let first = (stratum(low).floor() as u32).saturating_sub(1);
        let end = (stratum(high).floor() as u32).saturating_add(2).min(rays);
        first.min(end)..end
    }

    /// Whether every ray of the point surely misses `tracer`'s triangles,
    /// so that each scores 1 and the point's AO is 1 exactly, known
    /// without casting one: no triangle reaches the half ball its rays
    /// can hit in (see `trace::open`). A triangle the test cannot rule
    /// out (alpha-mask holes and all) keeps the point traced, so a point
    /// whose rays all miss may still be traced; one said to be open is
    /// open. The point's own triangle lies a ray offset below the rays'
    /// origin: where that is within the test's margin (a bias of nearly
    /// nothing, or coordinates thousands of radii from the world's
    /// origin), it keeps the point traced.
    pub fn surely_open(&self, tracer: &AoTracer) -> bool {
        let region = HalfBall::new(
            self.origin,
            Vec3A::from(self.n),
            self.p.radius,
            self.least_rise(),
        );
        !tracer.top.may_reach(&tracer.layers, &region)
    }

    /// Ray `k`'s squared sine of elevation from the normal: in the
    /// stratum `[k, k + 1) / rays`, random within it.
    fn r1(&self, k: u32) -> f32 {
        (k as f32 + uniform(self.p.seed, self.id, 3 * k)) / self.p.rays as f32
    }

    /// The least cosine between a ray and the normal, over the point's
    /// rays, less a margin for rounding (at least 0): every ray's
    /// direction lies within the cone of that cosine about the normal.
    /// The last ray's: its stratum lies above every other's (and rounding
    /// keeps that order), so it is the flattest.
    fn least_rise(&self) -> f32 {
        let last = self.p.rays.saturating_sub(1);
        ((1.0 - self.r1(last)).max(0.0).sqrt() - 1e-5).max(0.0)
    }

    /// Ray `k`'s score against `tracer`: `min(t, R) / R` for a
    /// closest-hit ray, 1 or 0 for a Laine-Karras one (misses or not).
    pub fn score(&self, tracer: &AoTracer, k: u32) -> f32 {
        let (dir, len) = self.ray(k);
        self.score_along(tracer, dir, len)
    }

    /// The score of the ray along `dir` traced to `len` (one of
    /// [`ray`](Self::ray)'s, kept), as [`score`](Self::score).
    pub fn score_along(&self, tracer: &AoTracer, dir: Vec3A, len: f32) -> f32 {
        let p = &self.p;
        match p.estimator {
            Estimator::ClosestHit => {
                let t = match tracer
                    .top
                    .closest(&tracer.layers, self.origin, dir, p.radius)
                {
                    Some(lead) => p.radius.min(lead - RAY_LEAD),
                    None => p.radius,
                };
                t / p.radius
            }
            Estimator::LaineKarras => {
                if tracer.top.misses(&tracer.layers, self.origin, dir, len) {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }
}

/// How far along its normal a ray starts from `point`: the configured bias
/// plus a part that grows with the coordinates, so the offset stays above
/// f32 rounding far from the origin.
pub fn ray_offset(bias: f32, point: Vec3) -> f32 {
    bias + point.abs().max_element() * (1.0 / (1u32 << 21) as f32)
}
