//! Point generation (paper 3.1): points spawned uniformly over a mesh's
//! surface, then weighted sample elimination (Yuksel 2015) down to half.

use glam::{IVec3, Vec3};
use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::error::{SceneError, check_param};
use crate::model::mesh::Mesh;
use crate::morton::morton_order;
use crate::random::uniform;

/// Where a point sits on its mesh: a triangle, barycentric weights and a
/// side. A deformed (skinned) mesh carries its points along through it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Anchor {
    /// Triangle index.
    pub triangle: u32,
    /// Barycentric weights of the triangle's three vertices (sum 1).
    pub weights: [f32; 3],
    /// Whether the point is on the back side (its normal is flipped).
    pub back: bool,
}

/// Points of one mesh, in its local space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointSet {
    /// Positions.
    pub positions: Vec<Vec3>,
    /// Unit normals (the surface side the point belongs to).
    pub normals: Vec<Vec3>,
    /// Where each point sits on the mesh.
    pub anchors: Vec<Anchor>,
    /// The Poisson disk radius of the kept points, `2 r_max` of the
    /// elimination: about the distance between neighbouring points, and
    /// the client's interpolation radius r (paper eq. 2). (`r_max`, the
    /// radius of non-overlapping disks, is half the spacing: with it as r,
    /// a quarter of the surface lay farther than r from every point and
    /// reconstructed as open; see BENCHMARKS.md, issue 4.)
    pub radius: f32,
}

impl PointSet {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Positions and normals of the points on `mesh` with its vertices at
    /// `positions` and `normals` (a deformed copy of the mesh the points
    /// were made for), written into `out_p` and `out_n`. A point whose
    /// anchor does not fit the mesh keeps its own position and normal.
    pub fn follow(
        &self,
        mesh: &Mesh,
        positions: &[Vec3],
        normals: &[Vec3],
        out_p: &mut Vec<Vec3>,
        out_n: &mut Vec<Vec3>,
    ) {
        out_p.clear();
        out_n.clear();
        for (k, a) in self.anchors.iter().enumerate() {
            let t = a.triangle as usize;
            let corners = mesh.indices.get(3 * t..3 * t + 3).map(|i| {
                [0, 1, 2].map(|c| (positions.get(i[c] as usize), normals.get(i[c] as usize)))
            });
            let (p, n) = match corners {
                Some(
                    [
                        (Some(&p0), Some(&n0)),
                        (Some(&p1), Some(&n1)),
                        (Some(&p2), Some(&n2)),
                    ],
                ) => {
                    let w = a.weights;
                    let p = p0 * w[0] + p1 * w[1] + p2 * w[2];
                    let face = (p1 - p0).cross(p2 - p0).normalize_or_zero();
                    let n = (n0 * w[0] + n1 * w[1] + n2 * w[2])
                        .try_normalize()
                        .unwrap_or(face);
                    (p, if a.back { -n } else { n })
                }
                _ => (self.positions[k], self.normals[k]),
            };
            out_p.push(p);
            out_n.push(n);
        }
    }
}

/// Checks a density of points spawned per unit area: any positive, finite
/// value (the spawned count is what is bounded).
pub(crate) fn check_density(density: f32) -> Result<(), SceneError> {
    check_param(
        "density",
        density as f64,
        f32::MIN_POSITIVE as f64,
        f32::MAX as f64,
        "points per unit area, positive and finite",
    )
}

/// Most points [`generate_points`] spawns for one mesh side.
pub const MAX_SPAWNED_POINTS: usize = 1 << 26;

/// Spawns `density` points per unit area over `mesh` (both sides of a
/// double-sided mesh, each with its own normal), rejects those in
/// alpha-mask holes, then eliminates half of the rest per side by weighted
/// sample elimination and fills the gaps that leaves on thin strips
/// ([`generate_points_with`] with `fill_gaps`). Deterministic for a seed.
pub fn generate_points(mesh: &Mesh, density: f32, seed: u64) -> Result<PointSet, SceneError> {
    generate_points_with(mesh, density, seed, true)
}

/// Fewest points spawned on a mesh side of positive area: a mesh smaller
/// than two points' worth of area (a bolt, a thin trim) still gets a few
/// points rather than none, so its pixels are not left open.
pub const MIN_SPAWNED: usize = 8;

/// As [`generate_points`]; with `fill_gaps`, a spawned point that
/// elimination left with no kept point facing its way within the
/// interpolation radius (`2 r_max`) is kept too (`gaps.rs`): strips
/// narrower than the point spacing keep a point every radius, not their
/// share of the area. Without it, the points are elimination's alone.
pub fn generate_points_with(
    mesh: &Mesh,
    density: f32,
    seed: u64,
    fill_gaps: bool,
) -> Result<PointSet, SceneError> {
    // Any positive density: the mesh's own units may be millimetres under
    // a node that scales them up (or metres for a model 7 mm across); the
    // spawned count below is what is bounded.
    check_density(density)?;
    mesh.validate(0)?;
    let area = mesh.area();
    let spawned = area as f64 * density as f64;
    check_param(
        "area x density",
        spawned,
        0.0,
        MAX_SPAWNED_POINTS as f64,
        "spawned points per side at most 2^26 (finite area)",
    )?;
    if spawned <= 0.0 {
        return Ok(PointSet::default());
    }
    let spawned = spawned.round() as usize;
    let spawned = if fill_gaps {
        spawned.max(MIN_SPAWNED)
    } else if spawned < 2 {
        return Ok(PointSet::default());
    } else {
        spawned
    };
    let sides: &[f32] = if mesh.double_sided {
        &[1.0, -1.0]
    } else {
        &[1.0]
    };
    let mut out = PointSet::default();
    for (s, &sign) in sides.iter().enumerate() {
        let (mut pos, mut nrm, mut anchors) = spawn(mesh, spawned, seed ^ ((s as u64) << 40));
        // Holes take their share of the area: the solid area is the
        // accepted fraction of the whole.
        let keep = pos.len() / 2;
        let solid_area = area * pos.len() as f32 / spawned as f32;
        let (kept, radius) = eliminate(&pos, &nrm, keep, solid_area);
        let kept = if fill_gaps && !kept.is_empty() {
            // Candidates along every triangle, so a strip thinner than
            // the spacing has some to fill with whatever its area.
            let reach = 2.0 * radius;
            let (p, n, a) = super::gaps::candidates(mesh, reach, seed ^ ((s as u64) << 40));
            pos.extend(p);
            nrm.extend(n);
            anchors.extend(a);
            super::gaps::fill_gaps(&pos, &nrm, kept, reach)
        } else {
            kept
        };
        out.radius = out.radius.max(2.0 * radius);
        for i in kept {
            out.positions.push(pos[i]);
            out.normals.push(nrm[i] * sign);
            out.anchors.push(Anchor {
                back: sign < 0.0,
                ..anchors[i]
            });
        }
    }
    Ok(out)
}

/// Spawned points per parallel task.
const SPAWN_CHUNK: usize = 1 << 14;

/// Spawned point `k`: a triangle drawn by area, a uniform spot on it;
/// `None` in an alpha-mask hole.
fn spawn_one(
    mesh: &Mesh,
    cdf: &[f64],
    total: f64,
    seed: u64,
    k: u32,
) -> Option<(Vec3, Vec3, Anchor)> {
    let tris = cdf.len();
    let pick = uniform(seed, 0, k) as f64 * total;
    let t = cdf.partition_point(|&c| c <= pick).min(tris - 1);
    let (r1, r2) = (uniform(seed, 1, k).sqrt(), uniform(seed, 2, k));
    point_on(mesh, t, [1.0 - r1, r1 * (1.0 - r2), r1 * r2])
}

/// The point of triangle `t` at barycentric weights `[wa, wb, wc]`, with
/// its interpolated unit normal (the face's where those cancel) and its
/// anchor; `None` in an alpha-mask hole.
pub(crate) fn point_on(
    mesh: &Mesh,
    t: usize,
    [wa, wb, wc]: [f32; 3],
) -> Option<(Vec3, Vec3, Anchor)> {
    if !mesh.solid(t, [wa, wb, wc]) {
        return None;
    }
    let i = &mesh.indices[3 * t..3 * t + 3];
    let [a, b, c] = mesh.triangle(t);
    let n = mesh.normals[i[0] as usize] * wa
        + mesh.normals[i[1] as usize] * wb
        + mesh.normals[i[2] as usize] * wc;
    let face = (b - a).cross(c - a).normalize_or_zero();
    Some((
        a * wa + b * wb + c * wc,
        n.try_normalize().unwrap_or(face),
        Anchor {
            triangle: t as u32,
            weights: [wa, wb, wc],
            back: false,
        },
    ))
}

/// `count` points uniform over the mesh's area, with interpolated normals
/// and their anchors; points in alpha-mask holes are left out.
fn spawn(mesh: &Mesh, count: usize, seed: u64) -> (Vec<Vec3>, Vec<Vec3>, Vec<Anchor>) {
    let tris = mesh.triangle_count();
    let mut cdf = Vec::with_capacity(tris);
    let mut total = 0.0f64;
    for t in 0..tris {
        let [a, b, c] = mesh.triangle(t);
        total += (b - a).cross(c - a).length() as f64 * 0.5;
        cdf.push(total);
    }
    // Each spawned point depends on its index alone: spawned in parallel,
    // in chunks kept in order, so the result does not depend on threads.
    let chunks: Vec<Vec<(Vec3, Vec3, Anchor)>> = (0..count.div_ceil(SPAWN_CHUNK))
        .into_par_iter()
        .map(|c| {
            let (lo, hi) = (c * SPAWN_CHUNK, ((c + 1) * SPAWN_CHUNK).min(count));
            (lo as u32..hi as u32)
                .filter_map(|k| spawn_one(mesh, &cdf, total, seed, k))
                .collect()
        })
        .collect();
    let kept: usize = chunks.iter().map(Vec::len).sum();
    let mut pos = Vec::with_capacity(kept);
    let mut nrm = Vec::with_capacity(kept);
    let mut anchors = Vec::with_capacity(kept);
    for (p, n, a) in chunks.into_iter().flatten() {
        pos.push(p);
        nrm.push(n);
        anchors.push(a);
    }
    (pos, nrm, anchors)
}

/// Weighted sample elimination of `points` with unit `normals` (spread
/// over `area`) down to `keep`. Points whose normals face away from each
/// other (opposite faces of thin geometry) do not count as neighbours.
/// Returns the kept indices and `r_max = sqrt(area / (2 sqrt(3) keep))`.
/// At most [`MAX_SPAWNED_POINTS`] points are considered; a non-finite or
/// non-positive `area` keeps the first `keep` points.
pub fn eliminate(points: &[Vec3], normals: &[Vec3], keep: usize, area: f32) -> (Vec<usize>, f32) {
    let n = points.len().min(normals.len()).min(MAX_SPAWNED_POINTS);
    let keep = keep.min(n);
    if keep == 0 {
        return (Vec::new(), 0.0);
    }
    if !area.is_finite() || area <= 0.0 {
        return ((0..keep).collect(), 0.0);
    }
    let r_max = (area / (2.0 * 3f32.sqrt() * keep as f32)).sqrt();
    let reach = 2.0 * r_max;
    // Weight limiting (Yuksel 2015, beta = 0.65, gamma = 1.5).
    let r_min = reach * (1.0 - (keep as f32 / n as f32).powf(1.5)) * 0.65;
    let weight = |d: f32| (1.0 - d.max(r_min) / reach).max(0.0).powi(8);

    if n <= 2 * TILE_POINTS {
        let neighbours = neighbour_lists(&points[..n], &normals[..n], reach);
        let all: Vec<u32> = (0..n as u32).collect();
        let kept = eliminate_tile(&all, &neighbours, keep, &weight, None, 1.0);
        return (kept.into_iter().map(|i| i as usize).collect(), r_max);
    }
    // Many points: Morton-ordered tiles of TILE_POINTS, eliminated in
    // parallel (see TILE_POINTS), the points renumbered in tile order so
    // that each tile's data lie together.
    let order = morton_order(&points[..n]);
    let (pts, nrm): (Vec<Vec3>, Vec<Vec3>) = order.iter().map(|&i| (points[i], normals[i])).unzip();
    let neighbours = neighbour_lists(&pts, &nrm, reach);
    let tiles = n.div_ceil(TILE_POINTS);
    let survive = keep as f32 / n as f32;
    let tile_of = |i: u32| i as usize / TILE_POINTS;
    let kept: Vec<Vec<u32>> = (0..tiles)
        .into_par_iter()
        .map(|t| {
            let (lo, hi) = (t * TILE_POINTS, ((t + 1) * TILE_POINTS).min(n));
            // Each tile keeps its share; the shares add up to `keep`.
            let share = |end: usize| (end as u64 * keep as u64 / n as u64) as usize;
            let ids: Vec<u32> = (lo as u32..hi as u32).collect();
            eliminate_tile(
                &ids,
                &neighbours,
                share(hi) - share(lo),
                &weight,
                Some((t, &tile_of)),
                survive,
            )
        })
        .collect();
    let mut out: Vec<usize> = kept
        .into_iter()
        .flatten()
        .map(|i| order[i as usize])
        .collect();
    out.sort_unstable();
    (out, r_max)
}

/// Points per tile of a large elimination. Up to twice this, one
/// elimination over all points; above, each Morton-ordered run of this
/// many points is eliminated on its own, in parallel. A point's
/// neighbours in other tiles count towards its weight at the share of
/// points kept (they are eliminated meanwhile, by their own tile), and
/// are never updated: the tiles' seams come out a little less even than
/// the inside (`points.rs` measures the spread).
pub const TILE_POINTS: usize = 1 << 16;

/// Weighted sample elimination of the points `ids` (ascending) down to
/// `keep`, with `neighbours` and `weight` of the distance. With `tile`
/// (this tile, and the tile of a point), neighbours outside the tile
/// weigh `outside` times their weight and are not updated. Returns the
/// kept ids, ascending.
fn eliminate_tile(
    ids: &[u32],
    neighbours: &Neighbours,
    keep: usize,
    weight: &(dyn Fn(f32) -> f32 + Sync),
    tile: Option<(usize, &(dyn Fn(u32) -> usize + Sync))>,
    outside: f32,
) -> Vec<u32> {
    let n = ids.len();
    let base = ids.first().copied().unwrap_or(0);
    // Local index of a neighbour in this tile, or None.
    let local = |j: u32| match tile {
        Some((t, tile_of)) if tile_of(j) != t => None,
        _ => Some((j - base) as usize),
    };
    // Start from +0.0: an empty float sum is -0.0, whose bits would sort
    // above every positive weight and eliminate isolated points first.
    let mut w: Vec<f32> = ids
        .iter()
        .map(|&i| {
            neighbours.of(i as usize).iter().fold(0.0, |a, &(j, d)| {
                a + match local(j) {
                    Some(_) => weight(d),
                    None => weight(d) * outside,
                }
            })
        })
        .collect();
    let key = |w: f32| (w + 0.0).to_bits();
    let mut heap = WeightHeap::new(w.iter().map(|&x| key(x)).collect());
    let mut removed = vec![false; n];
    let mut left = n;
    while left > keep {
        let Some(i) = heap.pop() else { break };
        let i = i as usize;
        removed[i] = true;
        left -= 1;
        for &(j, d) in neighbours.of(ids[i] as usize) {
            let Some(j) = local(j) else { continue };
            if !removed[j] {
                w[j] = (w[j] - weight(d)).max(0.0);
                heap.lower(j as u32, key(w[j]));
            }
        }
    }
    (0..n).filter(|&i| !removed[i]).map(|i| ids[i]).collect()
}

/// The points still in, as a max-heap by (weight bits, index) whose keys
/// only go down, lowered in place (the elimination's heap of Yuksel 2015):
/// every point once, instead of an entry per weight update. The order of
/// removal is the largest weight first, the larger index among equals.
struct WeightHeap {
    /// Point indices in heap order.
    heap: Vec<u32>,
    /// Per point, where it is in `heap`.
    at: Vec<u32>,
    /// Per point, its key (the weight's bits: non-negative floats order as
    /// their bits).
    key: Vec<u32>,
}

impl WeightHeap {
    fn new(key: Vec<u32>) -> WeightHeap {
        let n = key.len() as u32;
        let mut h = WeightHeap {
            heap: (0..n).collect(),
            at: (0..n).collect(),
            key,
        };
        for k in (0..h.heap.len() / 2).rev() {
            h.sift_down(k);
        }
        h
    }

    fn above(&self, a: u32, b: u32) -> bool {
        (self.key[a as usize], a) > (self.key[b as usize], b)
    }

    fn pop(&mut self) -> Option<u32> {
        let top = *self.heap.first()?;
        let last = self.heap.pop()?;
        if !self.heap.is_empty() {
            self.heap[0] = last;
            self.at[last as usize] = 0;
            self.sift_down(0);
        }
        Some(top)
    }

    /// Lowers point `i`'s key to `key` (not above its key now).
    fn lower(&mut self, i: u32, key: u32) {
        debug_assert!(key <= self.key[i as usize]);
        self.key[i as usize] = key;
        self.sift_down(self.at[i as usize] as usize);
    }

    fn sift_down(&mut self, mut k: usize) {
        let len = self.heap.len();
        loop {
            let mut top = k;
            for child in [2 * k + 1, 2 * k + 2] {
                if child < len && self.above(self.heap[child], self.heap[top]) {
                    top = child;
                }
            }
            if top == k {
                return;
            }
            self.heap.swap(k, top);
            self.at[self.heap[k] as usize] = k as u32;
            self.at[self.heap[top] as usize] = top as u32;
            k = top;
        }
    }
}

/// Neighbours within `reach` of every point: per chunk of
/// [`NEIGHBOUR_CHUNK`] points (listed in parallel), where each list starts
/// and the lists one after another.
struct Neighbours {
    chunks: Vec<NeighbourChunk>,
}

impl Neighbours {
    fn of(&self, i: usize) -> &[(u32, f32)] {
        let (starts, items) = &self.chunks[i / NEIGHBOUR_CHUNK];
        let k = i % NEIGHBOUR_CHUNK;
        &items[starts[k] as usize..starts[k + 1] as usize]
    }
}

/// One parallel task's lists: where each starts (one more than its
/// points), and their items one after another.
type NeighbourChunk = (Vec<u32>, Vec<(u32, f32)>);

/// Points whose neighbours one parallel task lists.
const NEIGHBOUR_CHUNK: usize = 1 << 12;

fn neighbour_lists(points: &[Vec3], normals: &[Vec3], reach: f32) -> Neighbours {
    let cell = |p: Vec3| (p / reach).floor().as_ivec3();
    // Points by cell: sorted in parallel (the index breaks ties, so the
    // order is one whatever the threads), then each cell's run indexed.
    let mut by_cell: Vec<(IVec3, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, &p)| (cell(p), i as u32))
        .collect();
    by_cell.par_sort_unstable_by_key(|&(c, i)| (c.x, c.y, c.z, i));
    let mut grid: FxHashMap<IVec3, (u32, u32)> = FxHashMap::default();
    let mut at = 0;
    while at < by_cell.len() {
        let c = by_cell[at].0;
        let mut end = at + 1;
        while end < by_cell.len() && by_cell[end].0 == c {
            end += 1;
        }
        grid.insert(c, (at as u32, end as u32));
        at = end;
    }
    // Each point's list depends on the grid alone: listed in parallel, in
    // chunks kept in order.
    let chunks: Vec<NeighbourChunk> = (0..points.len().div_ceil(NEIGHBOUR_CHUNK))
        .into_par_iter()
        .map(|c| {
            let (lo, hi) = (
                c * NEIGHBOUR_CHUNK,
                ((c + 1) * NEIGHBOUR_CHUNK).min(points.len()),
            );
            let (mut starts, mut items) = (Vec::with_capacity(hi - lo + 1), Vec::new());
            starts.push(0u32);
            for i in lo..hi {
                let (p, c) = (points[i], cell(points[i]));
                for dz in -1..=1 {
                    for dy in -1..=1 {
                        for dx in -1..=1 {
                            let Some(&(a, b)) = grid.get(&(c + IVec3::new(dx, dy, dz))) else {
                                continue;
                            };
                            for &(_, j) in &by_cell[a as usize..b as usize] {
                                let d = points[j as usize].distance(p);
                                let facing = normals[j as usize].dot(normals[i]) > 0.0;
                                if j as usize != i && d < reach && facing {
                                    items.push((j, d));
                                }
                            }
                        }
                    }
                }
                starts.push(items.len() as u32);
            }
            (starts, items)
        })
        .collect();
    Neighbours { chunks }
}
