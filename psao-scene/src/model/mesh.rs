//! Triangle meshes in their own (instance-local) space, optionally skinned
//! or alpha-masked, and the boxes that bound them.

use glam::{Affine3A, Vec3};

use crate::error::SceneError;
use crate::model::alpha::AlphaMask;
use crate::model::morph::MorphTargets;
use crate::model::skin::SkinWeights;

/// A triangle mesh in its own (instance-local) space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Vertex normals (unit length), one per position.
    pub normals: Vec<Vec3>,
    /// Triangle vertex indices, three per triangle, counter-clockwise front.
    pub indices: Vec<u32>,
    /// Whether both sides are surfaces (points are spawned on both).
    pub double_sided: bool,
    /// Joint influences, for instances with a skin.
    pub skin: Option<SkinWeights>,
    /// Morph targets whose weights an animation drives (applied before
    /// the skin); `None` when the weights never change (any default
    /// weights are applied to the positions at import).
    pub morph: Option<MorphTargets>,
    /// Where the surface has holes.
    pub alpha: Option<AlphaMask>,
}

impl Mesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// The corners of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        let i = &self.indices[3 * t..3 * t + 3];
        [
            self.positions[i[0] as usize],
            self.positions[i[1] as usize],
            self.positions[i[2] as usize],
        ]
    }

    /// Total surface area (one side).
    pub fn area(&self) -> f32 {
        (0..self.triangle_count())
            .map(|t| {
                let [a, b, c] = self.triangle(t);
                (b - a).cross(c - a).length() * 0.5
            })
            .sum()
    }

    /// Local bounding box `(min, max)`; `None` without vertices.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        bounds_of(&self.positions)
    }

    /// Checks indices, counts and finiteness. `mesh` names it in errors.
    pub fn validate(&self, mesh: usize) -> Result<(), SceneError> {
        if !self.indices.len().is_multiple_of(3) {
            return Err(SceneError::IndexCount {
                mesh,
                len: self.indices.len(),
            });
        }
        if self.normals.len() != self.positions.len() {
            return Err(SceneError::NormalCount {
                mesh,
                positions: self.positions.len(),
                normals: self.normals.len(),
            });
        }
        if let Some(vertex) = (0..self.positions.len())
            .find(|&v| !self.positions[v].is_finite() || !self.normals[v].is_finite())
        {
            return Err(SceneError::NonFiniteVertex { mesh, vertex });
        }
        if let Some(k) = self
            .indices
            .iter()
            .position(|&i| i as usize >= self.positions.len())
        {
            return Err(SceneError::IndexOutOfRange {
                mesh,
                triangle: k / 3,
                index: self.indices[k],
                vertices: self.positions.len(),
            });
        }
        let element = |what: &str, reason: String| SceneError::Element {
            element: format!("mesh {mesh} {what}"),
            reason,
        };
        if let Some(w) = &self.skin {
            let n = self.positions.len();
            if w.joints.len() != n || w.weights.len() != n {
                return Err(element(
                    "skin weights",
                    format!(
                        "{} joint sets and {} weight sets for {n} vertices",
                        w.joints.len(),
                        w.weights.len()
                    ),
                ));
            }
            if let Some(v) = w
                .weights
                .iter()
                .position(|w| w.iter().any(|x| !x.is_finite() || *x < 0.0))
            {
                return Err(element(
                    "skin weights",
                    format!("vertex {v} has a negative or non-finite weight"),
                ));
            }
        }
        if let Some(m) = &self.morph {
            m.check(self.positions.len())
                .map_err(|r| element("morph targets", r))?;
        }
        if let Some(a) = &self.alpha {
            a.check(self.positions.len())
                .map_err(|r| element("alpha mask", r))?;
        }
        Ok(())
    }

    /// Whether the surface is solid (not an alpha-mask hole) at barycentric
    /// weights `w` of triangle `t`.
    pub fn solid(&self, t: usize, w: [f32; 3]) -> bool {
        match (&self.alpha, self.indices.get(3 * t..3 * t + 3)) {
            (Some(a), Some(i)) => a.solid([i[0], i[1], i[2]], w),
            _ => true,
        }
    }

    /// An axis-aligned box `[min, max]`, normals facing out, 12 triangles.
    pub fn cuboid(min: Vec3, max: Vec3) -> Mesh {
        let mut m = Mesh::default();
        let c = [min, max];
        for axis in 0..3 {
            for side in 0..2 {
                let n = Vec3::AXES[axis] * if side == 0 { -1.0 } else { 1.0 };
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let corner = |a: usize, b: usize| {
                    let mut p = Vec3::ZERO;
                    p[axis] = c[side][axis];
                    p[u] = c[a][u];
                    p[v] = c[b][v];
                    p
                };
                let quad = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
                m.push_quad(quad, n);
            }
        }
        m
    }

    /// A rectangle with corner `origin` and edges `u`, `v`; its front faces
    /// `u x v`.
    pub fn quad(origin: Vec3, u: Vec3, v: Vec3) -> Mesh {
        let mut m = Mesh::default();
        let n = u.cross(v).normalize();
        m.push_quad([origin, origin + u, origin + u + v, origin + v], n);
        m
    }

    /// The same surface with every triangle split into four at its edge
    /// midpoints, `levels` times (4^levels as many triangles). Normals are
    /// interpolated and renormalized.
    /// Skin weights, morph targets and alpha masks are not carried over.
    pub fn subdivided(&self, levels: u32) -> Mesh {
        let mut m = self.clone();
        for _ in 0..levels {
            let mut next = Mesh {
                double_sided: m.double_sided,
                ..Mesh::default()
            };
            for t in 0..m.triangle_count() {
                let i = [0, 1, 2].map(|k| m.indices[3 * t + k] as usize);
                let p = i.map(|k| m.positions[k]);
                let n = i.map(|k| m.normals[k]);
                let mid =
                    |a: usize, b: usize| ((p[a] + p[b]) * 0.5, (n[a] + n[b]).normalize_or(n[a]));
                let (ab, bc, ca) = (mid(0, 1), mid(1, 2), mid(2, 0));
                let corners = [(p[0], n[0]), (p[1], n[1]), (p[2], n[2])];
                for tri in [
                    [corners[0], ab, ca],
                    [ab, corners[1], bc],
                    [ca, bc, corners[2]],
                    [ab, bc, ca],
                ] {
                    let base = next.positions.len() as u32;
                    for (q, nq) in tri {
                        next.positions.push(q);
                        next.normals.push(nq);
                    }
                    next.indices.extend([base, base + 1, base + 2]);
                }
            }
            m = next;
        }
        m
    }

    /// Appends a planar quad (two triangles) wound to face `n`.
    fn push_quad(&mut self, q: [Vec3; 4], n: Vec3) {
        let base = self.positions.len() as u32;
        let facing = (q[1] - q[0]).cross(q[2] - q[0]).dot(n) >= 0.0;
        self.positions.extend_from_slice(&q);
        self.normals.extend_from_slice(&[n; 4]);
        let order: [u32; 6] = if facing {
            [0, 1, 2, 0, 2, 3]
        } else {
            [0, 2, 1, 0, 3, 2]
        };
        self.indices.extend(order.iter().map(|i| base + i));
    }
}

/// The bounds of `points`; `None` without points.
pub fn bounds_of(points: &[Vec3]) -> Option<(Vec3, Vec3)> {
    let first = *points.first()?;
    Some(
        points
            .iter()
            .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
    )
}

/// The eight corners of the box `(lo, hi)`: corner `k` takes `hi`'s x,
/// y and z where bits 0, 1 and 2 of `k` are set, `lo`'s where not.
pub fn box_corners((lo, hi): (Vec3, Vec3)) -> [Vec3; 8] {
    std::array::from_fn(|k| {
        Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

/// The box holding a box `(lo, hi)` after transform `t`: the bounds of its
/// eight transformed corners.
pub fn transformed_bounds(t: &Affine3A, b: (Vec3, Vec3)) -> (Vec3, Vec3) {
    let mut out = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for corner in box_corners(b) {
        let w = t.transform_point3(corner);
        out = (out.0.min(w), out.1.max(w));
    }
    out
}
