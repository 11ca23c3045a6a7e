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
    /// Per instance, the morph weights of its mesh (empty for a mesh
    /// without animated [`MorphTargets`](crate::MorphTargets)).
    pub weights: Vec<Vec<f32>>,
    /// Per node, the morph weights an animation gives it now (empty where
    /// none does).
    node_weights: Vec<Vec<f32>>,
}

impl Scene {
    /// The scene at time `t` seconds.
    pub fn pose(&self, t: f32) -> Pose {
        let mut p = Pose::default();
        self.pose_into(t, &mut p);
        p
    }

    /// The scene at time `t` seconds given in f64
    /// ([`pose_into_at`](Self::pose_into_at)).
    pub fn pose_at(&self, t: f64) -> Pose {
        let mut p = Pose::default();
        self.pose_into_at(t, &mut p);
        p
    }

    /// The scene at time `t` seconds, reusing `pose`'s memory.
    pub fn pose_into(&self, t: f32, pose: &mut Pose) {
        // The same pose: an f32 time's place in each loop comes out the
        // same in f64 (Animation::local_time).
        self.pose_into_at(t as f64, pose);
    }

    /// The scene at time `t` seconds given in f64, reusing `pose`'s
    /// memory: each animation's time within its loop is taken in f64
    /// ([`Animation::local_time_at`](crate::Animation::local_time_at)), so that a scene posed at a time of
    /// hours or days moves as smoothly as in its first minute.
    pub fn pose_into_at(&self, t: f64, pose: &mut Pose) {
        pose.locals.clear();
        pose.locals.extend(self.nodes.iter().map(|n| n.trs));
        pose.node_weights.resize_with(self.nodes.len(), Vec::new);
        pose.node_weights.iter_mut().for_each(Vec::clear);
        for a in &self.animations {
            a.apply_at(t, &mut pose.locals);
            if a.drives_weights() {
                a.apply_weights_at(t, &mut pose.node_weights);
            }
        }
        compose(&self.nodes, &pose.locals, &mut pose.nodes);
        pose.instances.clear();
        pose.joints.resize_with(self.instances.len(), Vec::new);
        pose.weights.resize_with(self.instances.len(), Vec::new);
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
            let w = &mut pose.weights[i];
            w.clear();
            if let Some(m) = &self.meshes[inst.mesh].morph {
                match inst.node.and_then(|n| pose.node_weights.get(n)) {
                    Some(animated) if !animated.is_empty() => w.extend_from_slice(animated),
                    _ => w.extend_from_slice(&m.rest_weights),
                }
            }
        }
    }

    /// Whether instance `i`'s mesh changes shape: it has a skin (and joint
    /// weights) or animated morph targets.
    pub fn deforms(&self, i: usize) -> bool {
        let inst = &self.instances[i];
        let m = &self.meshes[inst.mesh];
        (inst.skin.is_some() && m.skin.is_some()) || m.morph.is_some()
    }

    /// The vertex positions and normals of instance `i`'s mesh in its
    /// local space under `pose`: morphed when it has animated morph
    /// targets, then skinned when it has a skin; else the mesh's own. The
    /// scene must be valid and `pose` made from it.
    pub fn deformed<'a>(&'a self, i: usize, pose: &Pose) -> (Cow<'a, [Vec3]>, Cow<'a, [Vec3]>) {
        if !self.deforms(i) {
            let m = &self.meshes[self.instances[i].mesh];
            return (Cow::Borrowed(&m.positions), Cow::Borrowed(&m.normals));
        }
        let (mut p, mut n) = (Vec::new(), Vec::new());
        self.deform_into(i, pose, &mut p, &mut n);
        (Cow::Owned(p), Cow::Owned(n))
    }

    /// [`deformed`](Self::deformed) into `out_p` and `out_n` (the mesh's
    /// own vertices for an instance that does not deform).
    pub fn deform_into(&self, i: usize, pose: &Pose, out_p: &mut Vec<Vec3>, out_n: &mut Vec<Vec3>) {
        let inst = &self.instances[i];
        let m = &self.meshes[inst.mesh];
        let morph = m.morph.as_ref().zip(pose.weights.get(i));
        let skin = match (&m.skin, pose.joints.get(i)) {
            (Some(w), Some(j)) if inst.skin.is_some() => Some((w, j)),
            _ => None,
        };
        match (morph, skin) {
            // Morphed straight into the caller's buffers.
            (Some((t, w)), None) => t.apply(w, &m.positions, &m.normals, out_p, out_n),
            (None, Some((w, j))) => w.skin(&m.positions, &m.normals, j, out_p, out_n),
            // Both: the morphed mesh is the skin's input.
            (Some((t, wt)), Some((w, j))) => {
                let (mut p, mut n) = (Vec::new(), Vec::new());
                t.apply(wt, &m.positions, &m.normals, &mut p, &mut n);
                w.skin(&p, &n, j, out_p, out_n);
            }
            (None, None) => {
                out_p.clear();
                out_p.extend_from_slice(&m.positions);
                out_n.clear();
                out_n.extend_from_slice(&m.normals);
            }
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
