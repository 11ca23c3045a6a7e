//! The scene model: meshes (optionally skinned or alpha-masked), their
//! instances, the node hierarchy, skins, animations and a camera path.

use glam::{Affine3A, Vec3};

use crate::alpha::AlphaMask;
use crate::animation::Animation;
use crate::camera::CameraPath;
use crate::error::SceneError;
use crate::node::{Node, Trs};
use crate::skin::{Skin, SkinWeights};

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
        if self.indices.len() % 3 != 0 {
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
    /// Skin weights and alpha masks are not carried over.
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

/// A placed copy of a mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    /// Index into [`Scene::meshes`].
    pub mesh: usize,
    /// Instance-local to world transform; with a `node`, relative to the
    /// node's world transform.
    pub transform: Affine3A,
    /// The node it hangs from (it moves with the node's animation).
    pub node: Option<usize>,
    /// The skin that deforms its mesh (index into [`Scene::skins`]); the
    /// mesh must carry [`SkinWeights`].
    pub skin: Option<usize>,
}

/// Meshes, instances, the node hierarchy, skins, animations and a camera
/// path. Time runs in seconds from 0; [`Scene::pose`] evaluates it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene {
    /// Meshes in their local space.
    pub meshes: Vec<Mesh>,
    /// Placed instances.
    pub instances: Vec<Instance>,
    /// The node hierarchy (parents before children).
    pub nodes: Vec<Node>,
    /// Skins.
    pub skins: Vec<Skin>,
    /// Animations; all of them play together, each looping over its own
    /// duration (see [`select_animation`](Self::select_animation)).
    pub animations: Vec<Animation>,
    /// The viewer's path, if the scene has one.
    pub camera: Option<CameraPath>,
}

impl Scene {
    /// Adds a mesh with one instance at `transform`; returns the instance index.
    pub fn add(&mut self, mesh: Mesh, transform: Affine3A) -> usize {
        self.meshes.push(mesh);
        self.instances.push(Instance {
            mesh: self.meshes.len() - 1,
            transform,
            node: None,
            skin: None,
        });
        self.instances.len() - 1
    }

    /// Appends everything of `other` (meshes, nodes, skins, animations,
    /// instances; not its camera), hanging its root nodes and its
    /// node-less instances from `parent`. Returns the range of the new
    /// instances.
    pub fn append(&mut self, other: Scene, parent: Option<usize>) -> std::ops::Range<usize> {
        let (meshes, nodes, skins) = (self.meshes.len(), self.nodes.len(), self.skins.len());
        let first = self.instances.len();
        self.meshes.extend(other.meshes);
        self.nodes.extend(other.nodes.into_iter().map(|mut n| {
            n.parent = n.parent.map(|p| p + nodes).or(parent);
            n
        }));
        self.skins.extend(other.skins.into_iter().map(|mut s| {
            s.joints.iter_mut().for_each(|j| *j += nodes);
            s
        }));
        self.animations
            .extend(other.animations.into_iter().map(|mut a| {
                a.channels.iter_mut().for_each(|c| c.node += nodes);
                a
            }));
        self.instances
            .extend(other.instances.into_iter().map(|mut i| {
                i.mesh += meshes;
                i.node = i.node.map(|n| n + nodes).or(parent);
                i.skin = i.skin.map(|s| s + skins);
                i
            }));
        first..self.instances.len()
    }

    /// Keeps only the animation named `name` (glTF files often hold
    /// alternatives, such as walk and run, that should not play together).
    pub fn select_animation(&mut self, name: &str) -> Result<(), SceneError> {
        let Some(k) = self.animations.iter().position(|a| a.name == name) else {
            return Err(SceneError::Element {
                element: format!("animation `{name}`"),
                reason: format!(
                    "not found (the scene has {:?})",
                    self.animations.iter().map(|a| &a.name).collect::<Vec<_>>()
                ),
            });
        };
        let keep = self.animations.swap_remove(k);
        self.animations = vec![keep];
        Ok(())
    }

    /// Adds a node; returns its index. `parent` must already exist.
    pub fn add_node(&mut self, name: &str, parent: Option<usize>, trs: Trs) -> usize {
        self.nodes.push(Node {
            name: name.to_string(),
            parent,
            trs,
        });
        self.nodes.len() - 1
    }

    /// Adds a mesh with one instance hanging from `node`; returns the
    /// instance index.
    pub fn add_on_node(&mut self, mesh: Mesh, node: usize) -> usize {
        let i = self.add(mesh, Affine3A::IDENTITY);
        self.instances[i].node = Some(node);
        i
    }

    /// Checks every mesh, node, skin, animation, the camera path and every
    /// instance (its transform in the pose at time 0).
    pub fn validate(&self) -> Result<(), SceneError> {
        for (i, m) in self.meshes.iter().enumerate() {
            m.validate(i)?;
        }
        let element = |element: String, reason: String| SceneError::Element { element, reason };
        for (i, n) in self.nodes.iter().enumerate() {
            if n.parent.is_some_and(|p| p >= i) {
                return Err(element(
                    format!("node {i} ({})", n.name),
                    "its parent does not come before it".into(),
                ));
            }
            if !n.trs.is_finite() {
                return Err(element(
                    format!("node {i} ({})", n.name),
                    "transform is not finite".into(),
                ));
            }
        }
        for (i, s) in self.skins.iter().enumerate() {
            let name = || format!("skin {i} ({})", s.name);
            if let Some(j) = s.joints.iter().find(|&&j| j >= self.nodes.len()) {
                return Err(element(
                    name(),
                    format!("joint node {j} of {}", self.nodes.len()),
                ));
            }
            if s.inverse_bind.len() != s.joints.len() {
                return Err(element(
                    name(),
                    format!(
                        "{} inverse bind matrices for {} joints",
                        s.inverse_bind.len(),
                        s.joints.len()
                    ),
                ));
            }
            if !s.inverse_bind.iter().all(|m| m.is_finite()) {
                return Err(element(
                    name(),
                    "an inverse bind matrix is not finite".into(),
                ));
            }
        }
        for (a, anim) in self.animations.iter().enumerate() {
            for (c, ch) in anim.channels.iter().enumerate() {
                ch.validate(self.nodes.len(), a, c)?;
            }
        }
        if let Some(c) = &self.camera {
            c.validate()?;
        }
        for (i, inst) in self.instances.iter().enumerate() {
            if inst.mesh >= self.meshes.len() {
                return Err(SceneError::MeshOutOfRange {
                    instance: i,
                    mesh: inst.mesh,
                    meshes: self.meshes.len(),
                });
            }
            if let Some(n) = inst.node.filter(|&n| n >= self.nodes.len()) {
                return Err(element(
                    format!("instance {i}"),
                    format!("hangs from node {n} of {}", self.nodes.len()),
                ));
            }
            if let Some(s) = inst.skin {
                let Some(skin) = self.skins.get(s) else {
                    return Err(element(
                        format!("instance {i}"),
                        format!("uses skin {s} of {}", self.skins.len()),
                    ));
                };
                let Some(w) = &self.meshes[inst.mesh].skin else {
                    return Err(element(
                        format!("instance {i}"),
                        "has a skin but its mesh has no joint weights".into(),
                    ));
                };
                if let Some(v) = w
                    .joints
                    .iter()
                    .position(|j| j.iter().any(|&j| j as usize >= skin.joints.len()))
                {
                    return Err(element(
                        format!("mesh {} skin weights", inst.mesh),
                        format!(
                            "vertex {v} names a joint past the {} of skin {s}",
                            skin.joints.len()
                        ),
                    ));
                }
            }
        }
        let pose = self.pose(0.0);
        for (i, inst) in self.instances.iter().enumerate() {
            let bounds = if inst.skin.is_some() {
                let (p, _) = self.skinned(i, &pose);
                if !p.iter().all(|v| v.is_finite()) {
                    return Err(element(
                        format!("instance {i}"),
                        "its skinned vertices are not finite at time 0".into(),
                    ));
                }
                bounds_of(&p)
            } else {
                self.meshes[inst.mesh].bounds()
            };
            check_transform(i, &pose.instances[i], bounds)?;
        }
        Ok(())
    }

    /// Every instance's triangles in world space in the pose at time 0
    /// (skins applied), in instance order, after
    /// [`validate`](Self::validate).
    pub fn world_triangles(&self) -> Result<Vec<[Vec3; 3]>, SceneError> {
        self.validate()?;
        let pose = self.pose(0.0);
        let mut out = Vec::new();
        for (i, inst) in self.instances.iter().enumerate() {
            let m = &self.meshes[inst.mesh];
            let at = &pose.instances[i];
            let (positions, _) = self.skinned(i, &pose);
            for t in 0..m.triangle_count() {
                let idx = &m.indices[3 * t..3 * t + 3];
                let tri = [0, 1, 2].map(|k| at.transform_point3(positions[idx[k] as usize]));
                if !tri.iter().all(|p| p.is_finite()) {
                    return Err(SceneError::BadTransform { instance: i });
                }
                out.push(tri);
            }
        }
        Ok(out)
    }
}

/// Checks an instance's world transform: finite, invertible, and keeping
/// the mesh's `bounds` finite.
pub(crate) fn check_transform(
    instance: usize,
    t: &Affine3A,
    bounds: Option<(Vec3, Vec3)>,
) -> Result<(), SceneError> {
    let det = t.matrix3.determinant();
    if !t.is_finite() || !det.is_finite() || det.abs() < 1e-12 {
        return Err(SceneError::BadTransform { instance });
    }
    // Finite vertices under a finite transform can still overflow: the
    // transformed bounds must be finite too.
    if let Some(b) = bounds {
        let (lo, hi) = transformed_bounds(t, b);
        if !lo.is_finite() || !hi.is_finite() {
            return Err(SceneError::BadTransform { instance });
        }
    }
    Ok(())
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

/// The box holding a box `(lo, hi)` after transform `t`: the bounds of its
/// eight transformed corners.
pub fn transformed_bounds(t: &Affine3A, (lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3) {
    let mut out = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for k in 0..8 {
        let corner = Vec3::new(
            if k & 1 == 0 { lo.x } else { hi.x },
            if k & 2 == 0 { lo.y } else { hi.y },
            if k & 4 == 0 { lo.z } else { hi.z },
        );
        let w = t.transform_point3(corner);
        out = (out.0.min(w), out.1.max(w));
    }
    out
}
