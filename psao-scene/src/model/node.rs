//! The node hierarchy: local translation-rotation-scale transforms composed
//! from the root down.

use glam::{Affine3A, Quat, Vec3};

/// A local transform as translation, rotation and scale (applied scale
/// first, then rotation, then translation, as in glTF).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trs {
    /// Translation.
    pub translation: Vec3,
    /// Rotation (unit quaternion).
    pub rotation: Quat,
    /// Scale per axis.
    pub scale: Vec3,
}

impl Default for Trs {
    fn default() -> Self {
        Trs {
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
        }
    }
}

impl Trs {
    /// A pure translation.
    pub fn from_translation(t: Vec3) -> Trs {
        Trs {
            translation: t,
            ..Trs::default()
        }
    }

    /// The affine transform.
    pub fn affine(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(
            self.scale,
            normalize_quat(self.rotation),
            self.translation,
        )
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.translation.is_finite() && self.rotation.is_finite() && self.scale.is_finite()
    }
}

/// A node of the hierarchy. A node's parent comes before it in
/// [`Scene::nodes`](crate::Scene::nodes), so one pass from the front
/// composes every world transform and no cycle can be built.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Node {
    /// Name (for messages).
    pub name: String,
    /// The parent node, at a lower index; `None` for a root.
    pub parent: Option<usize>,
    /// The rest transform relative to the parent (animations override
    /// parts of it).
    pub trs: Trs,
}

/// World transforms of `nodes` whose local transforms are `locals`
/// (parents before children; see [`Node`]). Writes into `out`.
pub fn compose(nodes: &[Node], locals: &[Trs], out: &mut Vec<Affine3A>) {
    out.clear();
    for (i, (n, l)) in nodes.iter().zip(locals).enumerate() {
        let local = l.affine();
        let world = match n.parent {
            Some(p) if p < i => out[p] * local,
            _ => local,
        };
        out.push(world);
    }
}

/// `q` scaled to unit length; the identity when that is impossible (zero
/// or not finite).
pub fn normalize_quat(q: Quat) -> Quat {
    let len = q.length();
    if len.is_finite() && len > 1e-12 {
        q / len
    } else {
        Quat::IDENTITY
    }
}
