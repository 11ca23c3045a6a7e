//! The BVHs a pipeline traces against: static geometry in one world-space
//! BVH built once, each dynamic instance in its own local-space BVH placed
//! by its transform and refitted when it deforms, the primitives of one
//! skinned mesh (one node, one skin) in one BVH together (or, unsplit, one
//! BVH over everything). The tracer puts a BVH over these layers' boxes.

use std::sync::Arc;

use super::{InstanceState, Pipeline};
use crate::trace::ao::AoTracer;
use crate::trace::geometry::{Geometry, Layer, TriangleBvh};

impl Pipeline {
    /// Instance `i`'s triangles (with alpha masks) as they are now, in its
    /// local space, or in world space with `world`.
    pub(super) fn instance_geometry(&self, i: usize, world: bool, g: &mut Geometry) {
        let (s, inst) = (&self.instances[i], &self.scene.instances[i]);
        let m = &self.scene.meshes[inst.mesh];
        let verts = if s.vertices.is_empty() {
            &m.positions
        } else {
            &s.vertices
        };
        let mask = &self.masks[inst.mesh];
        for t in 0..m.triangle_count() {
            let idx = &m.indices[3 * t..3 * t + 3];
            let corner = |k: usize| {
                let p = verts[idx[k] as usize];
                if world {
                    s.transform.transform_point3(p)
                } else {
                    p
                }
            };
            g.triangles.push([corner(0), corner(1), corner(2)]);
            g.masks
                .push(mask.as_ref().map(|m| (m.clone(), [idx[0], idx[1], idx[2]])));
        }
    }

    /// World-space geometry of the instances `pick` selects.
    fn world_geometry(&self, pick: impl Fn(&InstanceState) -> bool) -> Geometry {
        let mut g = Geometry::default();
        for i in 0..self.instances.len() {
            if pick(&self.instances[i]) {
                self.instance_geometry(i, true, &mut g);
            }
        }
        g
    }

    /// The tracer for the scene now. With a split BVH, static geometry
    /// sits in one world-space BVH built once, and each dynamic instance in
    /// its own local-space BVH, placed by its transform (rigid motion
    /// rebuilds nothing) and refitted when it deforms (see
    /// [`refit_deformed`](Self::refit_deformed)). Unsplit, one world-space
    /// BVH over everything is rebuilt whenever `changed`.
    pub(super) fn tracer(&mut self, changed: bool) -> AoTracer {
        if !self.config.split_bvh {
            if changed || self.whole_layer.is_none() {
                self.whole_layer = Some(Arc::new(TriangleBvh::new(self.world_geometry(|_| true))));
            }
            return AoTracer::from_layers(
                self.whole_layer.iter().cloned().map(Layer::world).collect(),
            );
        }
        if self.static_layer.is_none() {
            self.static_layer = Some(Arc::new(TriangleBvh::new(
                self.world_geometry(|s| !s.dynamic),
            )));
        }
        let mut layers: Vec<Layer> = self
            .static_layer
            .iter()
            .cloned()
            .map(Layer::world)
            .collect();
        // Skinned instances that deform as one, while their transforms
        // agree (a held pose or a placed instance can part them).
        let mut grouped = vec![false; self.instances.len()];
        for g in 0..self.skin_groups.len() {
            let members = &self.skin_groups[g].members;
            let transform = self.instances[members[0]].transform;
            if members
                .iter()
                .any(|&m| self.instances[m].transform != transform)
            {
                continue;
            }
            if self.skin_groups[g].bvh.is_none() {
                let geometry = self.group_geometry(g);
                self.skin_groups[g].bvh = Some(Arc::new(TriangleBvh::refittable(geometry)));
            }
            let group = &self.skin_groups[g];
            for &m in &group.members {
                grouped[m] = true;
            }
            layers.extend(group.bvh.clone().map(|b| Layer::placed(b, transform)));
        }
        for (i, &in_group) in grouped.iter().enumerate() {
            if !self.instances[i].dynamic || in_group {
                continue;
            }
            if self.instances[i].bvh.is_none() {
                let mut g = Geometry::default();
                self.instance_geometry(i, false, &mut g);
                let bvh = if self.instances[i].vertices.is_empty() {
                    TriangleBvh::new(g)
                } else {
                    TriangleBvh::refittable(g)
                };
                self.instances[i].bvh = Some(Arc::new(bvh));
            }
            let s = &self.instances[i];
            layers.extend(s.bvh.clone().map(|b| Layer::placed(b, s.transform)));
        }
        AoTracer::from_layers(layers)
    }

    /// The local triangles of skin group `g`'s members, one after another.
    fn group_geometry(&self, g: usize) -> Geometry {
        let mut geometry = Geometry::default();
        for &m in &self.skin_groups[g].members {
            self.instance_geometry(m, false, &mut geometry);
        }
        geometry
    }

    /// Refits the BVH of every instance in `deformed` to its mesh as it is
    /// now, and the BVH of every skin group with a member among them.
    pub(super) fn refit_deformed(&mut self, deformed: &[usize]) {
        for g in 0..self.skin_groups.len() {
            let group = &self.skin_groups[g];
            if group.bvh.is_none() || !group.members.iter().any(|m| deformed.contains(m)) {
                continue;
            }
            let geometry = self.group_geometry(g);
            if let Some(bvh) = &mut self.skin_groups[g].bvh {
                Arc::make_mut(bvh).refit(&geometry.triangles);
            }
        }
        for &i in deformed {
            if self.instances[i].bvh.is_none() {
                continue;
            }
            let mut g = Geometry::default();
            self.instance_geometry(i, false, &mut g);
            if let Some(bvh) = &mut self.instances[i].bvh {
                Arc::make_mut(bvh).refit(&g.triangles);
            }
        }
    }
}
