//! The scene: instances of meshes, the node hierarchy, skins, animations
//! and a camera path, and the checks that make it sound to stream.

use glam::{Affine3A, Vec3};

use crate::error::SceneError;
use crate::model::animation::Animation;
use crate::model::camera::CameraPath;
use crate::model::mesh::{Mesh, bounds_of, transformed_bounds};
use crate::model::node::{Node, Trs};
use crate::model::skin::Skin;

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
    /// mesh must carry [`SkinWeights`](crate::SkinWeights).
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
    /// The sign that turns the winding normal of instance `i`'s triangles
    /// (counter-clockwise, in world space under `world`, its transform now)
    /// into the normal of their front: +1, -1 when `world` mirrors
    /// (negative determinant: glTF flips the winding), 0 for a
    /// double-sided mesh, which has no back. The scene must be valid.
    pub fn front_sign(&self, i: usize, world: &Affine3A) -> f32 {
        if self.meshes[self.instances[i].mesh].double_sided {
            0.0
        } else if world.matrix3.determinant() < 0.0 {
            -1.0
        } else {
            1.0
        }
    }

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

    /// The shortest time, in seconds, after which every animation starts
    /// again together (each loops over its own duration): the longest
    /// duration times the least whole number, up to 16, that every other
    /// duration divides (to a part in 10^6, so that rounds stay in step
    /// over many of them), each at most 10^4 times. `None` where nothing
    /// animates (no animation lasts longer than 0), or where that time
    /// would pass `longest` seconds or no such number exists.
    pub fn loop_period(&self, longest: f32) -> Option<f32> {
        let durations: Vec<f32> = self
            .animations
            .iter()
            .map(Animation::duration)
            .filter(|d| d.is_finite() && *d > 0.0)
            .collect();
        let base = durations.iter().copied().reduce(f32::max)?;
        (1..=16u32)
            .map(|m| base * m as f32)
            .take_while(|&p| p <= longest)
            .find(|&p| {
                durations.iter().all(|&d| {
                    let r = p as f64 / d as f64;
                    r <= 1e4 && (r - r.round()).abs() <= 1e-6 * r
                })
            })
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
            let bounds = if self.deforms(i) {
                let (p, _) = self.deformed(i, &pose);
                if !p.iter().all(|v| v.is_finite()) {
                    return Err(element(
                        format!("instance {i}"),
                        "its deformed vertices are not finite at time 0".into(),
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
            let (positions, _) = self.deformed(i, &pose);
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

/// Fewest of `|det M|` per `|m0| |m1| |m2|` (the product of `M`'s column
/// lengths) an instance transform may have: how far from flat its linear
/// part is, whatever its scale. The ratio is 1 for a rotation times any
/// scale (ToyCar's nodes scale by 1e-4: determinant 1e-12, ratio 1) and 0
/// for a singular matrix (an axis scaled to zero to hide an object); 1e-6
/// refuses only matrices sheared almost into a plane, whose inverse f32
/// cannot give to more than a few digits.
pub const MIN_TRANSFORM_RATIO: f64 = 1e-6;

/// Whether `t` is finite, its inverse is finite, and its linear part is
/// not near singular relative to its own scale ([`MIN_TRANSFORM_RATIO`],
/// computed in f64, so tiny scales do not underflow the ratio; the f32
/// inverse must still be finite, which holds for scales down to about
/// 1e-13).
pub fn invertible(t: &Affine3A) -> bool {
    if !t.is_finite() {
        return false;
    }
    let m = glam::DMat3::from_cols(
        t.matrix3.x_axis.as_dvec3(),
        t.matrix3.y_axis.as_dvec3(),
        t.matrix3.z_axis.as_dvec3(),
    );
    let scale = m.x_axis.length() * m.y_axis.length() * m.z_axis.length();
    let det = m.determinant();
    scale > 0.0 && det.abs() >= MIN_TRANSFORM_RATIO * scale && t.inverse().is_finite()
}

/// Checks an instance's world transform: finite, [`invertible`], and
/// keeping the mesh's `bounds` finite.
pub(crate) fn check_transform(
    instance: usize,
    t: &Affine3A,
    bounds: Option<(Vec3, Vec3)>,
) -> Result<(), SceneError> {
    if !invertible(t) {
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
