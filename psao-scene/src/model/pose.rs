//! Evaluating a scene at a time: node transforms after animation, instance
//! world transforms and skin joint matrices.

use std::borrow::Cow;

use glam::{Affine3A, Vec3};

use crate::model::node::{Trs, compose};
use crate::model::scene::Scene;

/// A scene at one moment.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pose {
    /// Local transform of every node (rest values with animations applied).
    pub locals: Vec<Trs>,
    /// World transform of every node.
    pub nodes: Vec<Affine3A>,
    /// World transform of every instance.
    pub instances: Vec<Affine3A>,
    /// Per instance, its skin's joint matrices in the instance's local
    /// space (empty for an instance without a skin).
    pub joints: Vec<Vec<Affine3A>>,
}

impl Scene {
    /// The scene at time `t` seconds.
    pub fn pose(&self, t: f32) -> Pose {
        let mut p = Pose::default();
        self.pose_into(t, &mut p);
        p
    }

    /// The scene at time `t` seconds, reusing `pose`'s memory.
    pub fn pose_into(&self, t: f32, pose: &mut Pose) {
        pose.locals.clear();
        pose.locals.extend(self.nodes.iter().map(|n| n.trs));
        for a in &self.animations {
            a.apply(t, &mut pose.locals);
        }
        compose(&self.nodes, &pose.locals, &mut pose.nodes);
        pose.instances.clear();
        pose.joints.resize_with(self.instances.len(), Vec::new);
        for (i, inst) in self.instances.iter().enumerate() {
            let world = match inst.node.and_then(|n| pose.nodes.get(n)) {
                Some(n) => *n * inst.transform,
                None => inst.transform,
            };
            pose.instances.push(world);
            match inst.skin.and_then(|s| self.skins.get(s)) {
                Some(skin) => skin.joint_matrices(&pose.nodes, &world, &mut pose.joints[i]),
                None => pose.joints[i].clear(),
            }
        }
    }

    /// The vertex positions and normals of instance `i`'s mesh in its
    /// local space under `pose` (skinned when it has a skin, else the
    /// mesh's own). The scene must be valid and `pose` made from it.
    pub fn skinned<'a>(&'a self, i: usize, pose: &Pose) -> (Cow<'a, [Vec3]>, Cow<'a, [Vec3]>) {
        let inst = &self.instances[i];
        let m = &self.meshes[inst.mesh];
        match (&m.skin, pose.joints.get(i)) {
            (Some(w), Some(j)) if inst.skin.is_some() => {
                let (mut p, mut n) = (Vec::new(), Vec::new());
                w.skin(&m.positions, &m.normals, j, &mut p, &mut n);
                (Cow::Owned(p), Cow::Owned(n))
            }
            _ => (Cow::Borrowed(&m.positions), Cow::Borrowed(&m.normals)),
        }
    }

    /// Per instance, whether anything about it can change over time: it
    /// hangs from a node that an animation drives (or below one), or it has
    /// a skin with such a joint.
    pub fn dynamic_instances(&self) -> Vec<bool> {
        let mut animated = vec![false; self.nodes.len()];
        for c in self.animations.iter().flat_map(|a| &a.channels) {
            if let Some(x) = animated.get_mut(c.node) {
                *x = true;
            }
        }
        for i in 0..self.nodes.len() {
            if let Some(p) = self.nodes[i].parent.filter(|&p| p < i) {
                animated[i] |= animated[p];
            }
        }
        let on = |n: usize| animated.get(n).copied().unwrap_or(false);
        self.instances
            .iter()
            .map(|inst| {
                inst.node.is_some_and(on)
                    || inst
                        .skin
                        .and_then(|s| self.skins.get(s))
                        .is_some_and(|s| s.joints.iter().any(|&j| on(j)))
            })
            .collect()
    }

    /// The longest animation's duration (0 without animations).
    pub fn duration(&self) -> f32 {
        self.animations
            .iter()
            .map(|a| a.duration())
            .fold(0.0, f32::max)
    }
}

/// The matrix that carries normals through `t`: the inverse transpose of
/// its linear part (normals stay perpendicular to surfaces under
/// non-uniform scale).
pub fn normal_matrix(t: &glam::Affine3A) -> glam::Mat3A {
    t.matrix3.inverse().transpose()
}
