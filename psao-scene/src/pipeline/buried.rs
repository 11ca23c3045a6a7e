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
use psao_codec::{Placement, PointWord, WeightParams, weight};
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
    /// Every (donor id, index into `ids` of a buried point it gives to),
    /// ascending: which buried points a donor's new word reaches.
    by_donor: Vec<(u32, u32)>,
    /// What the next fill must look at (see [`Refill`]).
    refill: Refill,
}

/// Which buried points of an instance the next fill recomputes. A buried
/// point's AO follows only from its donors' held words (and the fixed
/// positions and normals of the points of a rigid instance), so one whose
/// donors kept their words since the last fill would get the value it got
/// then, which it holds already (or which was within the thresholds of
/// what it holds): only the points that a changed donor gives to, and
/// those that did not get a slot (they retry), need a look.
#[derive(Clone, Debug, Default)]
enum Refill {
    /// Every buried point: none filled yet, or more donors changed than
    /// are worth listing.
    #[default]
    All,
    /// The donors whose held word was set since the last fill (in any
    /// order, perhaps repeated), and the indices (into `ids`, ascending)
    /// of the buried points the last fill left without a slot.
    Some {
        changed: Vec<u32>,
        unplaced: Vec<u32>,
    },
}

impl Buried {
    /// The buried points `ids` and their donors (nearest first).
    pub(super) fn new(ids: Vec<u32>, donors: Vec<Vec<u32>>) -> Buried {
        let mut by_donor: Vec<(u32, u32)> = donors
            .iter()
            .enumerate()
            .flat_map(|(b, list)| list.iter().map(move |&d| (d, b as u32)))
            .collect();
        by_donor.sort_unstable();
        by_donor.dedup();
        Buried {
            ids,
            donors,
            by_donor,
            refill: Refill::All,
        }
    }

    /// Whether point `k` is buried (and so not traced).
    pub(super) fn contains(&self, k: u32) -> bool {
        self.ids.binary_search(&k).is_ok()
    }

    /// Notes that the word clients hold for point `k` was set: if it is a
    /// donor, the next fill looks at the buried points it gives to.
    pub(super) fn note_set(&mut self, k: u32) {
        if self.ids.is_empty() {
            return;
        }
        let at = self.by_donor.partition_point(|&(d, _)| d < k);
        if self.by_donor.get(at).is_none_or(|&(d, _)| d != k) {
            return;
        }
        if let Refill::Some { changed, .. } = &mut self.refill {
            if changed.len() >= self.by_donor.len() {
                // Listing more than there are pairs gains nothing.
                self.refill = Refill::All;
            } else {
                changed.push(k);
            }
        }
    }

    /// The indices (into `ids`, ascending) of the buried points the next
    /// fill must recompute; `None`: all of them. Starts a new round of
    /// notes.
    fn take_refill(&mut self) -> Option<Vec<u32>> {
        match std::mem::replace(
            &mut self.refill,
            Refill::Some {
                changed: Vec::new(),
                unplaced: Vec::new(),
            },
        ) {
            Refill::All => None,
            Refill::Some {
                mut changed,
                unplaced,
            } => {
                changed.sort_unstable();
                changed.dedup();
                // Those without a slot, and those a changed donor gives to.
                let mut which = unplaced;
                for d in changed {
                    let from = self.by_donor.partition_point(|&(x, _)| x < d);
                    which.extend(
                        self.by_donor[from..]
                            .iter()
                            .take_while(|&&(x, _)| x == d)
                            .map(|&(_, b)| b),
                    );
                }
                which.sort_unstable();
                which.dedup();
                Some(which)
            }
        }
    }

    /// Bytes held.
    pub(super) fn memory_bytes(&self) -> u64 {
        let refill = match &self.refill {
            Refill::All => 0,
            Refill::Some { changed, unplaced } => changed.capacity() + unplaced.capacity(),
        };
        (self.ids.capacity() * 4
            + self.donors.capacity() * std::mem::size_of::<Vec<u32>>()
            + self.donors.iter().map(|d| d.capacity() * 4).sum::<usize>()
            + self.by_donor.capacity() * 8
            + refill * 4) as u64
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
    /// else when past the thresholds). Returns how many were set. Without
    /// `force` only the buried points whose donors' words were set since
    /// the last fill ([`Buried::note_set`]), and those still without a
    /// slot, are recomputed: the others would get the value they got last
    /// time, which they hold. (With thresholds under which setting a
    /// point to what it holds counts as a change, as a negative
    /// `position_quanta`, a fill of every buried point would set those
    /// again, to the same words: the frames are the same, and `updated`
    /// counts fewer.)
    pub(super) fn fill_buried(&mut self, touched: &[bool], force: bool) -> Result<u64, SceneError> {
        let th = self.config.thresholds;
        let mut set = 0u64;
        let mut held: Vec<(Vec3, Vec3, f32)> = Vec::new();
        for (s, &touched) in self.instances.iter_mut().zip(touched) {
            if s.buried.ids.is_empty() || !touched {
                continue;
            }
            let which = s.buried.take_refill().filter(|_| !force);
            let which: Vec<u32> = which.unwrap_or_else(|| (0..s.buried.ids.len() as u32).collect());
            let params = WeightParams::of(s.table.def());
            let (positions, normals) = (&s.points.positions, &s.points.normals);
            let mut values = Vec::with_capacity(which.len());
            for &b in &which {
                let (k, donors) = (s.buried.ids[b as usize], &s.buried.donors[b as usize]);
                let (x, nx) = (positions[k as usize], normals[k as usize]);
                held.clear();
                held.extend(donors.iter().filter_map(|&d| {
                    let (p, n) = (positions[d as usize], normals[d as usize]);
                    let word: PointWord = s.table.sent(d, p, n).word;
                    word.is_allocated().then(|| (p, n, word.ao()))
                }));
                values.push(blend(&held, x, nx, &params));
            }
            let mut unplaced = Vec::new();
            for (&b, value) in which.iter().zip(values) {
                let k = s.buried.ids[b as usize];
                if let Some(ao) = value {
                    let (p, n) = (positions[k as usize], normals[k as usize]);
                    if force {
                        s.table.set_point(k, p, n, ao)?;
                        set += 1;
                    } else if s.table.update_point(k, p, n, ao, &th)? {
                        set += 1;
                    }
                }
                if !matches!(s.table.placement(k), Placement::Stored { .. }) {
                    // Without a slot (or never set): looked at again.
                    unplaced.push(b);
                }
            }
            if let Refill::Some { unplaced: u, .. } = &mut s.buried.refill {
                *u = unplaced;
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
    let (mut kept, mut donors) = (Vec::new(), Vec::new());
    for (k, list) in ids.into_iter().zip(lists) {
        if !list.is_empty() {
            kept.push(k);
            donors.push(list);
        }
    }
    Buried::new(kept, donors)
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Vec3};

    use super::*;
    use crate::{Animation, Mesh, PipelineConfig, RayBudget, Scene, Trs};

    /// A floor, a table whose block's top face lies hidden under its top
    /// (buried points on the block and on the floor under it), and a box
    /// sliding past the table's foot: the floor points next to the foot
    /// (donors of the buried ones under it) change as the box passes.
    fn scene() -> Scene {
        let mut s = Scene::default();
        s.add(
            Mesh::quad(Vec3::new(-3.0, 0.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0).subdivided(2),
            Affine3A::IDENTITY,
        );
        s.add(crate::hall_table(), Affine3A::IDENTITY);
        let slider = s.add(
            Mesh::cuboid(Vec3::new(-0.15, 0.0, -0.15), Vec3::new(0.15, 0.3, 0.15)),
            Affine3A::IDENTITY,
        );
        let node = s.add_node("slide", None, Trs::default());
        s.instances[slider].node = Some(node);
        s.animations.push(Animation::translation(
            "slide",
            node,
            &[
                (0.0, Vec3::new(-1.5, 0.0, -0.55)),
                (2.0, Vec3::new(1.5, 0.0, -0.55)),
            ],
        ));
        s
    }

    /// Buried points whose held word a fill of every buried point would
    /// now set (their donors' blend is past the thresholds of what they
    /// hold), over all instances.
    fn behind(p: &Pipeline) -> usize {
        let th = p.config.thresholds;
        let mut out = 0;
        for s in &p.instances {
            let params = WeightParams::of(s.table.def());
            let (positions, normals) = (&s.points.positions, &s.points.normals);
            for (&k, donors) in s.buried.ids.iter().zip(&s.buried.donors) {
                let held: Vec<(Vec3, Vec3, f32)> = donors
                    .iter()
                    .filter_map(|&d| {
                        let (q, n) = (positions[d as usize], normals[d as usize]);
                        let word = s.table.sent(d, q, n).word;
                        word.is_allocated().then(|| (q, n, word.ao()))
                    })
                    .collect();
                let (x, nx) = (positions[k as usize], normals[k as usize]);
                if let Some(ao) = blend(&held, x, nx, &params)
                    && s.table.sent(k, x, nx).changed(ao, &th)
                {
                    out += 1;
                }
            }
        }
        out
    }

    #[test]
    fn buried_points_refilled_only_where_donors_changed_hold_what_a_full_fill_gives() {
        for (budget, settle) in [
            (RayBudget::Unlimited, 0),
            (RayBudget::Rays(3_000), 0),
            (RayBudget::Unlimited, 1),
        ] {
            let mut c = PipelineConfig::with_density_and_rays(256.0, 32);
            c.budget = budget;
            c.settle_steps = settle;
            let mut p = Pipeline::new(scene(), c).unwrap();
            assert!(p.buried_points() > 0);
            assert_eq!(behind(&p), 0, "after setup");
            let held = |p: &Pipeline| -> Vec<u32> {
                p.instances
                    .iter()
                    .flat_map(|s| {
                        s.buried.ids.iter().map(|&k| {
                            let (x, n) =
                                (s.points.positions[k as usize], s.points.normals[k as usize]);
                            s.table.sent(k, x, n).word.0
                        })
                    })
                    .collect()
            };
            let before = held(&p);
            for step in 0..40 {
                p.step(0.05).unwrap();
                assert_eq!(behind(&p), 0, "{budget:?}, settle {settle}, step {step}");
            }
            // Some buried points' words changed on the way (their donors
            // did): the check above had something to see.
            let moved = held(&p).iter().zip(&before).filter(|(a, b)| a != b).count();
            assert!(moved > 0, "{budget:?}: no buried point's word changed");
        }
    }

    #[test]
    fn refilling_where_donors_changed_sends_what_refilling_every_buried_point_sends() {
        // Against a fill of every buried point each step (the refill set
        // to all before each step), the same frames, updates and drops:
        // also where cells are too small for every point (no overflow,
        // two a cell), so that buried points without a slot retry.
        let cases = [
            (false, RayBudget::Rays(3_000)),
            (true, RayBudget::Unlimited),
            (true, RayBudget::Rays(3_000)),
        ];
        for (k, (crowded, budget)) in cases.into_iter().enumerate() {
            let mut c = PipelineConfig::with_density_and_rays(256.0, 16);
            c.budget = budget;
            if crowded {
                c.layout.overflow = false;
                c.layout.cell_capacity = 2;
            }
            let mut some = Pipeline::new(scene(), c.clone()).unwrap();
            let mut all = Pipeline::new(scene(), c).unwrap();
            // Points without a slot now, and drop events so far.
            let dropped = |p: &Pipeline| -> (u64, u64) {
                p.instances.iter().fold((0, 0), |(n, e), s| {
                    let t = s.table.stats();
                    let events = t.cell_overflow + t.bucket_overflow + t.out_of_grid;
                    (n + u64::from(t.dropped), e + events)
                })
            };
            let mut refilled = 0;
            for step in 0..30 {
                for s in &mut all.instances {
                    s.buried.refill = Refill::All;
                }
                let (a, ra) = some.step(0.05).unwrap();
                let (b, rb) = all.step(0.05).unwrap();
                let bytes = |f: Option<psao_codec::EncodedFrame>| f.map(|f| f.bytes.to_vec());
                assert_eq!(bytes(a), bytes(b), "case {k}, step {step}: frames");
                assert_eq!(ra.updated, rb.updated, "case {k}, step {step}: updated");
                assert_eq!(
                    dropped(&some),
                    dropped(&all),
                    "case {k}, step {step}: drops"
                );
                refilled += rb.updated;
            }
            assert!(refilled > 0, "case {k}: nothing was set");
            if crowded {
                // The crowded layouts leave points without a slot.
                assert!(dropped(&some).0 > 0, "case {k}: no point was dropped");
            }
        }
    }
}
