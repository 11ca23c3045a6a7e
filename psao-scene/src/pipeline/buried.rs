//! Buried points: points on faces hidden inside other geometry (the top
//! of a table's leg under its top, a pier's base sunk in the floor, the
//! floor under a wall). Nobody sees them, but their AO (near 0: every ray
//! starts inside a solid) reaches the pixels of the visible surface next
//! to them, where the reconstruction (spec/wire-format.md 7.3) blends
//! points of like normal within its radius; a stack of faces a few
//! centimetres apart passes its plane test. That made blocks of dark
//! pixels where the surface is open (issue 14's artifact).
//!
//! At setup each point of a rigid instance is probed with
//! [`PROBE_RAYS_PER_POINT`] rays (the static world for a static instance,
//! its own mesh for a moving one; deforming instances are not probed): a
//! point whose every probe ray first meets the back face of a single-sided
//! triangle is inside a solid. A buried point takes the AO its visible
//! neighbours have (their held words, weighed as the reconstruction weighs
//! them from the buried point, with the second pass at twice the radius);
//! it is not traced. One with no visible neighbour within twice the
//! radius affects no pixel's first pass and is traced as any other. The
//! probe runs on the CPU whatever the backend and before the first trace,
//! so both backends stream the same frames.

use std::sync::Arc;

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::ray::Ray;
use psao_codec::{PointWord, WeightParams, weight};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::{Pipeline, SetupProgress, SetupStage};
use crate::error::SceneError;
use crate::model::pose::normal_matrix;
use crate::random::uniform;
use crate::trace::ao::ray_offset;
use crate::trace::geometry::{Geometry, TriangleBvh};

/// Probe rays per point.
pub const PROBE_RAYS_PER_POINT: u32 = 8;

/// Most visible neighbours a buried point takes its AO from (the nearest).
pub const MAX_DONORS: usize = 32;

/// The buried points of one instance and the visible neighbours each
/// takes its AO from.
#[derive(Clone, Debug, Default)]
pub(super) struct Buried {
    /// Buried point ids, ascending.
    pub(super) ids: Vec<u32>,
    /// Per buried point, its donors' ids (nearest first).
    pub(super) donors: Vec<Vec<u32>>,
}

impl Buried {
    /// Whether point `k` is buried (and so not traced).
    pub(super) fn contains(&self, k: u32) -> bool {
        self.ids.binary_search(&k).is_ok()
    }

    /// Bytes held.
    pub(super) fn memory_bytes(&self) -> u64 {
        (self.ids.capacity() * 4
            + self.donors.capacity() * std::mem::size_of::<Vec<u32>>()
            + self.donors.iter().map(|d| d.capacity() * 4).sum::<usize>()) as u64
    }
}

/// Triangles to probe against, with per triangle the sign that makes its
/// winding normal point out of its front (`+1`, `-1` under a mirroring
/// transform) or `0` for a double-sided one (it has no inside).
struct Probe {
    bvh: Arc<TriangleBvh>,
    normals: Vec<Vec3>,
}

impl Probe {
    /// The probe over `geometry`, each triangle's winding normal times its
    /// sign in `signs`.
    fn new(geometry: Geometry, signs: &[f32]) -> Probe {
        let normals = geometry
            .triangles
            .iter()
            .zip(signs)
            .map(|(t, s)| (t[1] - t[0]).cross(t[2] - t[0]) * *s)
            .collect();
        Probe {
            bvh: Arc::new(TriangleBvh::new(geometry)),
            normals,
        }
    }

    /// Whether every probe ray from `p` (normal `n`) first meets a back
    /// face of a single-sided triangle.
    fn buried(&self, p: Vec3, n: Vec3, id: u32, seed: u64, bias: f32) -> bool {
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO || !p.is_finite() {
            return false;
        }
        let origin = p + n * ray_offset(bias, p);
        let (t1, t2) = n.any_orthonormal_pair();
        (0..PROBE_RAYS_PER_POINT).all(|r| {
            // Cosine-weighted directions, stratified in azimuth.
            let u = uniform(seed, id, 2 * r);
            let v = (r as f32 + uniform(seed, id, 2 * r + 1)) / PROBE_RAYS_PER_POINT as f32;
            let (s, phi) = (u.sqrt(), std::f32::consts::TAU * v);
            let dir = (t1 * (s * phi.cos()) + t2 * (s * phi.sin()) + n * (1.0 - u).max(0.0).sqrt())
                .normalize_or(n);
            let ray = Ray::new(Vec3A::from(origin), Vec3A::from(dir), 0.0, f32::INFINITY);
            match self.bvh.closest_triangle(ray) {
                Some((t, _)) => self
                    .normals
                    .get(t as usize)
                    .is_some_and(|m| m.dot(dir) > 0.0),
                None => false,
            }
        })
    }
}

impl Pipeline {
    /// Finds every rigid instance's buried points and their donors (see
    /// the module). Deterministic: each point's probe depends on its id and
    /// the seed alone.
    pub(super) fn find_buried(
        &mut self,
        progress: &(dyn Fn(SetupProgress) + Sync),
    ) -> Result<(), SceneError> {
        let total = self.instances.len() as u64;
        progress(SetupProgress {
            stage: SetupStage::Buried,
            done: 0,
            total,
        });
        let seed = self.config.seed ^ 0xB0B1_ED00;
        let bias = self.config.ao.bias;
        let deforms: Vec<bool> = (0..self.instances.len())
            .map(|i| self.scene.deforms(i))
            .collect();
        // The static world, as the tracer's static layer holds it.
        let mut geometry = Geometry::default();
        let mut signs = Vec::new();
        for i in 0..self.instances.len() {
            if self.instances[i].dynamic {
                continue;
            }
            self.instance_geometry(i, true, &mut geometry);
            signs.resize(geometry.triangles.len(), self.face_sign(i, true));
        }
        let world = (!geometry.triangles.is_empty()).then(|| Probe::new(geometry, &signs));
        // The CPU tracer's static layer is this same BVH: built once.
        if let Some(w) = &world
            && self.backend.is_none()
            && self.config.split_bvh
            && self.static_layer.is_none()
        {
            self.static_layer = Some(w.bvh.clone());
        }
        // Each moving rigid mesh in its own space, once per mesh.
        let mut local: FxHashMap<usize, Arc<Probe>> = FxHashMap::default();
        let mut probes: Vec<Option<(Arc<Probe>, bool)>> = Vec::with_capacity(self.instances.len());
        let world = world.map(Arc::new);
        for (i, &deforming) in deforms.iter().enumerate() {
            let s = &self.instances[i];
            let probe = if deforming || s.points.is_empty() {
                None
            } else if !s.dynamic {
                world.clone().map(|w| (w, true))
            } else {
                let mesh = self.scene.instances[i].mesh;
                let p = match local.get(&mesh) {
                    Some(p) => p.clone(),
                    None => {
                        let mut g = Geometry::default();
                        self.instance_geometry(i, false, &mut g);
                        let signs = vec![self.face_sign(i, false); g.triangles.len()];
                        let p = Arc::new(Probe::new(g, &signs));
                        local.insert(mesh, p.clone());
                        p
                    }
                };
                Some((p, false))
            };
            probes.push(probe);
        }
        let mut base = 0u32;
        for (i, probe) in probes.into_iter().enumerate() {
            progress(SetupProgress {
                stage: SetupStage::Buried,
                done: i as u64,
                total,
            });
            let s = &self.instances[i];
            let first_id = base;
            base += s.points.len() as u32;
            let Some((probe, in_world)) = probe else {
                continue;
            };
            let (positions, normals) = s.now();
            let to = if in_world {
                s.transform
            } else {
                Affine3A::IDENTITY
            };
            let nm = normal_matrix(&to);
            let buried: Vec<bool> = (0..positions.len())
                .into_par_iter()
                .map(|k| {
                    let p = to.transform_point3(positions[k]);
                    let n = nm * normals[k];
                    probe.buried(p, n, first_id + k as u32, seed, bias)
                })
                .collect();
            if !buried.contains(&true) {
                continue;
            }
            let found = donors_of(
                positions,
                normals,
                &buried,
                &WeightParams::of(s.table.def()),
            );
            self.instances[i].buried = found;
        }
        progress(SetupProgress {
            stage: SetupStage::Buried,
            done: total,
            total,
        });
        Ok(())
    }

    /// The sign that turns instance `i`'s triangle windings (in world
    /// space with `world`, else its own) into front normals
    /// ([`Scene::front_sign`](crate::Scene::front_sign)).
    fn face_sign(&self, i: usize, world: bool) -> f32 {
        let at = if world {
            self.instances[i].transform
        } else {
            Affine3A::IDENTITY
        };
        self.scene.front_sign(i, &at)
    }

    /// Points of `which` that are traced: buried ones are left out.
    pub(super) fn traced_only(&self, which: &[Vec<u32>]) -> Option<Vec<Vec<u32>>> {
        if self.instances.iter().all(|s| s.buried.ids.is_empty()) {
            return None;
        }
        Some(
            which
                .iter()
                .zip(&self.instances)
                .map(|(w, s)| {
                    if s.buried.ids.is_empty() {
                        w.clone()
                    } else {
                        w.iter()
                            .copied()
                            .filter(|&k| !s.buried.contains(k))
                            .collect()
                    }
                })
                .collect(),
        )
    }

    /// Gives the buried points of every `touched` instance the AO of
    /// their donors as clients hold it (set whatever it was with `force`,
    /// else when past the thresholds). Returns how many were set.
    pub(super) fn fill_buried(&mut self, touched: &[bool], force: bool) -> Result<u64, SceneError> {
        let th = self.config.thresholds;
        let mut set = 0u64;
        let mut held: Vec<(Vec3, Vec3, f32)> = Vec::new();
        for (s, &touched) in self.instances.iter_mut().zip(touched) {
            if s.buried.ids.is_empty() || !touched {
                continue;
            }
            let params = WeightParams::of(s.table.def());
            let (positions, normals) = (&s.points.positions, &s.points.normals);
            let mut values = Vec::with_capacity(s.buried.ids.len());
            for (&k, donors) in s.buried.ids.iter().zip(&s.buried.donors) {
                let (x, nx) = (positions[k as usize], normals[k as usize]);
                held.clear();
                held.extend(donors.iter().filter_map(|&d| {
                    let (p, n) = (positions[d as usize], normals[d as usize]);
                    let word: PointWord = s.table.sent(d, p, n).word;
                    word.is_allocated().then(|| (p, n, word.ao()))
                }));
                values.push(blend(&held, x, nx, &params));
            }
            for (&k, value) in s.buried.ids.iter().zip(values) {
                let Some(ao) = value else { continue };
                let (p, n) = (positions[k as usize], normals[k as usize]);
                if force {
                    s.table.set_point(k, p, n, ao)?;
                    set += 1;
                } else if s.table.update_point(k, p, n, ao, &th)? {
                    set += 1;
                }
            }
        }
        Ok(set)
    }

    /// Buried points over all instances (not traced; see the module).
    pub fn buried_points(&self) -> u64 {
        self.instances
            .iter()
            .map(|s| s.buried.ids.len() as u64)
            .sum()
    }

    /// Whether point `k` of instance `i` is buried (not traced: it takes
    /// its visible neighbours' AO). False for an index past the end.
    pub fn is_buried(&self, i: usize, k: u32) -> bool {
        self.instances.get(i).is_some_and(|s| s.buried.contains(k))
    }
}

/// The reconstruction's blend of `held` (position, normal, AO) at `x`
/// with normal `nx`: radius r, then 2r; `None` when both weigh nothing.
fn blend(held: &[(Vec3, Vec3, f32)], x: Vec3, nx: Vec3, params: &WeightParams) -> Option<f32> {
    for scale in [1.0, 2.0] {
        let w = WeightParams {
            radius: params.radius * scale,
            ..*params
        };
        let (mut sum, mut total) = (0.0f32, 0.0f32);
        for &(p, n, ao) in held {
            let k = weight(p, n, x, nx, &w);
            sum += k * ao;
            total += k;
        }
        if total > 0.0 {
            return Some((sum / total).clamp(0.0, 1.0));
        }
    }
    None
}

/// For each buried point (`buried[k]`), the visible points within twice
/// the reconstruction radius that the reconstruction's tests let weigh on
/// it at 2r (nearest first, at most [`MAX_DONORS`]). Buried points without
/// any are left out (they are traced).
fn donors_of(
    positions: &[Vec3],
    normals: &[Vec3],
    buried: &[bool],
    params: &WeightParams,
) -> Buried {
    let reach = 2.0 * params.radius;
    if !(reach.is_finite() && reach > 0.0) {
        return Buried::default();
    }
    let cell = |p: Vec3| (p / reach).floor().as_ivec3();
    let mut grid: FxHashMap<glam::IVec3, Vec<u32>> = FxHashMap::default();
    for (k, p) in positions.iter().enumerate() {
        if !buried[k] {
            grid.entry(cell(*p)).or_default().push(k as u32);
        }
    }
    let wide = WeightParams {
        radius: reach,
        ..*params
    };
    let ids: Vec<u32> = (0..positions.len() as u32)
        .filter(|&k| buried[k as usize])
        .collect();
    let lists: Vec<Vec<u32>> = ids
        .par_iter()
        .map(|&k| {
            let (x, nx) = (positions[k as usize], normals[k as usize]);
            let c = cell(x);
            let mut near: Vec<(f32, u32)> = Vec::new();
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let Some(list) = grid.get(&(c + glam::IVec3::new(dx, dy, dz))) else {
                            continue;
                        };
                        for &d in list {
                            let (p, n) = (positions[d as usize], normals[d as usize]);
                            if weight(p, n, x, nx, &wide) > 0.0 {
                                near.push((p.distance_squared(x), d));
                            }
                        }
                    }
                }
            }
            near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            near.truncate(MAX_DONORS);
            near.into_iter().map(|(_, d)| d).collect()
        })
        .collect();
    let mut out = Buried::default();
    for (k, list) in ids.into_iter().zip(lists) {
        if !list.is_empty() {
            out.ids.push(k);
            out.donors.push(list);
        }
    }
    out
}
