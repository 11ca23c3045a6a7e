//! Acceleration structures of a scene: one BLAS per mesh in its local
//! space (built once), one per skinned instance (rebuilt from its skinned
//! vertices when the pose changes), and a TLAS of the instances placed by
//! their transforms, rebuilt for every pose. Triangles and instances reach
//! the builder in median-split order ([`TriangleOrder`]): some builders
//! (lavapipe's) group by input order.

use psao_scene::Scene;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::server::alpha::AlphaTables;

/// One BLAS with its input buffers.
#[derive(Debug)]
struct MeshBlas {
    blas: wgpu::Blas,
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    size: wgpu::BlasTriangleGeometrySizeDescriptor,
}

impl MeshBlas {
    /// A BLAS over `positions` and `indices` (uploaded now, built by the
    /// next [`GpuScene::build`]).
    fn new(
        ctx: &GpuContext,
        positions: &[glam::Vec3],
        indices: &[u32],
        dynamic: bool,
        opaque: bool,
    ) -> MeshBlas {
        let flat: Vec<[f32; 3]> = positions.iter().map(|p| p.to_array()).collect();
        let usage = wgpu::BufferUsages::BLAS_INPUT | wgpu::BufferUsages::COPY_DST;
        let vertices = ctx.buffer_with("psao-gpu vertices", bytemuck::cast_slice(&flat), usage);
        let indices_buf = ctx.buffer_with(
            "psao-gpu indices",
            bytemuck::cast_slice(indices),
            wgpu::BufferUsages::BLAS_INPUT,
        );
        let size = wgpu::BlasTriangleGeometrySizeDescriptor {
            vertex_format: wgpu::VertexFormat::Float32x3,
            vertex_count: positions.len() as u32,
            index_format: Some(wgpu::IndexFormat::Uint32),
            index_count: Some(indices.len() as u32),
            // Alpha-masked geometry reports candidate hits to the shader.
            flags: if opaque {
                wgpu::AccelerationStructureGeometryFlags::OPAQUE
            } else {
                wgpu::AccelerationStructureGeometryFlags::empty()
            },
        };
        let blas = ctx.device.create_blas(
            &wgpu::CreateBlasDescriptor {
                label: Some("psao-gpu blas"),
                flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE,
                update_mode: if dynamic {
                    wgpu::AccelerationStructureUpdateMode::PreferUpdate
                } else {
                    wgpu::AccelerationStructureUpdateMode::Build
                },
            },
            wgpu::BlasGeometrySizeDescriptors::Triangles {
                descriptors: vec![size.clone()],
            },
        );
        MeshBlas {
            blas,
            vertices,
            indices: indices_buf,
            size,
        }
    }

    fn entry(&self) -> wgpu::BlasBuildEntry<'_> {
        wgpu::BlasBuildEntry {
            blas: &self.blas,
            geometry: wgpu::BlasGeometries::TriangleGeometries(vec![wgpu::BlasTriangleGeometry {
                size: &self.size,
                vertex_buffer: &self.vertices,
                first_vertex: 0,
                vertex_stride: 12,
                index_buffer: Some(&self.indices),
                first_index: Some(0),
                transform_buffer: None,
                transform_buffer_offset: None,
            }]),
        }
    }
}

/// The order in which a mesh's triangles reach the BLAS builder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TriangleOrder {
    /// As the mesh lists them.
    AsGiven,
    /// Neighbours together: the order of a median-split tree of the
    /// triangles' bounds (halve at the median of their centres along the
    /// axis whose halves have the least surface area, then each half
    /// likewise). Some builders (lavapipe's) group triangles by their
    /// input order, and trace much faster this way.
    #[default]
    MedianSplit,
}

/// `indices` with the triangles in the order of a median-split tree of
/// their bounds ([`median_split_order`]). lavapipe's BLAS builder keeps
/// neighbours in its input order together: on the default scene's figure,
/// rays run several times faster with its triangles in this order than in
/// the file's (`examples/gpu_mesh_size.rs`). Triangles are whole and each
/// appears once, so only primitive indices change, and the alpha tables
/// use the same order.
fn spatial_order(positions: &[glam::Vec3], indices: &[u32]) -> Vec<u32> {
    let corner = |i: u32| positions.get(i as usize).copied().unwrap_or_default();
    let boxes: Vec<Bounds> = indices
        .chunks_exact(3)
        .map(|t| {
            let (a, b, c) = (corner(t[0]), corner(t[1]), corner(t[2]));
            (a.min(b).min(c), a.max(b).max(c))
        })
        .collect();
    median_split_order(&boxes)
        .into_iter()
        .flat_map(|t| indices[3 * t..3 * t + 3].iter().copied())
        .collect()
}

/// An axis-aligned box: (min, max).
type Bounds = (glam::Vec3, glam::Vec3);

/// The bounds of `vertices`; a point at the origin for none.
fn vertex_bounds(vertices: &[glam::Vec3]) -> Bounds {
    psao_scene::bounds_of(vertices).unwrap_or_default()
}

/// The box holding every box of `items`.
fn union(boxes: &[Bounds], items: &[usize]) -> Bounds {
    items.iter().fold(
        (
            glam::Vec3::splat(f32::INFINITY),
            glam::Vec3::splat(f32::NEG_INFINITY),
        ),
        |(lo, hi), &i| (lo.min(boxes[i].0), hi.max(boxes[i].1)),
    )
}

/// The centre of box `i` along `axis`.
fn centre(boxes: &[Bounds], i: usize, axis: usize) -> f32 {
    (boxes[i].0[axis] + boxes[i].1[axis]) * 0.5
}

/// Puts the first `ceil(len / 2)` of `part` by their centres along `axis`
/// first; returns the surface area of the two halves' bounds together (an
/// area beyond f32 counts as infinite).
fn split_at_median(boxes: &[Bounds], part: &mut [usize], axis: usize) -> f32 {
    let mid = part.len().div_ceil(2);
    part.select_nth_unstable_by(mid, |&a, &b| {
        centre(boxes, a, axis).total_cmp(&centre(boxes, b, axis))
    });
    let cost = half_area(union(boxes, &part[..mid])) + half_area(union(boxes, &part[mid..]));
    if cost.is_nan() { f32::INFINITY } else { cost }
}

/// The axis [`median_split_order`] splits `part` (two boxes or more)
/// along: the least surface area of the halves, and on a tie the widest
/// spread of centres. Leaves `part` split along axis 2.
fn best_split(boxes: &[Bounds], part: &mut [usize]) -> usize {
    let spread = |part: &[usize], axis: usize| {
        let (lo, hi) = part
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &i| {
                let c = centre(boxes, i, axis);
                (lo.min(c), hi.max(c))
            });
        hi - lo
    };
    let mut best = (f32::INFINITY, f32::NEG_INFINITY, 0);
    for axis in 0..3 {
        let cost = split_at_median(boxes, part, axis);
        let key = (cost, spread(part, axis), axis);
        if key.0 < best.0 || key.0 == best.0 && key.1 > best.1 {
            best = key;
        }
    }
    best.2
}

/// Half the surface area of a box.
fn half_area((lo, hi): Bounds) -> f32 {
    let d = (hi - lo).max(glam::Vec3::ZERO);
    d.x * d.y + d.y * d.z + d.z * d.x
}

/// The order of `boxes` as the leaves of a median-split tree: each node
/// halves its boxes at the median of their centres, the first half taking
/// the odd one, along the axis whose two halves have the least surface
/// area together (the surface area heuristic, with the halves' sizes
/// fixed); then each half likewise.
///
/// lavapipe's builder (Mesa 25.0) makes exactly this shape from its input
/// order: every node splits its range of leaves in the middle, the first
/// half taking the odd one. So the tree it builds over this order is the
/// tree described here. This order (with the odd leaf where lavapipe puts
/// it, the axis by surface area, and TLAS instances by their world bounds)
/// raised lavapipe's closest-hit rays per second on the default scene by
/// about a seventh over the longest-axis split of the centres
/// (BENCHMARKS.md).
fn median_split_order(boxes: &[Bounds]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    let mut stack = vec![(0, order.len())];
    while let Some((lo, hi)) = stack.pop() {
        if hi - lo < 2 {
            continue;
        }
        let part = &mut order[lo..hi];
        let best = best_split(boxes, part);
        if best != 2 {
            split_at_median(boxes, part, best);
        }
        let mid = part.len().div_ceil(2);
        stack.push((lo, lo + mid));
        stack.push((lo + mid, hi));
    }
    order
}

/// The BLAS that places instance `i` in the TLAS: its own when it is
/// skinned, else its mesh's; `None` for an instance without triangles.
/// The TLAS holds exactly the instances this gives a BLAS for.
fn placed_blas<'a>(
    scene: &Scene,
    meshes: &'a [Option<MeshBlas>],
    skinned: &'a [Option<MeshBlas>],
    i: usize,
) -> Option<&'a MeshBlas> {
    let inst = &scene.instances[i];
    let rigid = !scene.deforms(i);
    match (&skinned[i], &meshes[inst.mesh]) {
        (Some(b), _) => Some(b),
        (None, Some(b)) if rigid => Some(b),
        _ => None,
    }
}

/// The layout of a scene that its acceleration structures depend on.
#[derive(Clone, Debug, PartialEq)]
struct Shape {
    meshes: Vec<(usize, usize)>,
    instances: Vec<(usize, bool)>,
}

impl Shape {
    fn of(scene: &Scene) -> Shape {
        Shape {
            meshes: scene
                .meshes
                .iter()
                .map(|m| (m.positions.len(), m.indices.len()))
                .collect(),
            instances: scene
                .instances
                .iter()
                .enumerate()
                .map(|(k, i)| (i.mesh, scene.deforms(k)))
                .collect(),
        }
    }
}

/// A scene's acceleration structures on the GPU, posed at one time.
#[derive(Debug)]
pub struct GpuScene {
    /// Per mesh (not skinned), its BLAS; `None` for a mesh without
    /// triangles or used only skinned.
    meshes: Vec<Option<MeshBlas>>,
    /// Per instance with a skin, its own BLAS.
    skinned: Vec<Option<MeshBlas>>,
    /// The instances placed, or `None` when there is no triangle at all.
    tlas: Option<wgpu::Tlas>,
    /// The alpha masks, per instance.
    alpha: AlphaTables,
    /// What the structures were built for: per mesh (vertices, indices),
    /// per instance (mesh, skinned); `pose` and `place` refuse another
    /// scene.
    shape: Shape,
    /// Per instance, the bounds of its local vertices (its mesh's, or its
    /// skinned ones as last placed); placed by the transforms, they order
    /// the TLAS.
    local_bounds: Vec<Bounds>,
    triangles: usize,
    time: f32,
}

impl GpuScene {
    /// Uploads `scene` and builds its acceleration structures posed at
    /// time 0, each mesh's triangles in [`TriangleOrder::MedianSplit`].
    /// Alpha-masked meshes are not opaque to the rays: the AO pass tests
    /// each candidate hit against the mask. A scene beyond the device's
    /// limits is refused ([`GpuError::Limits`]).
    pub fn new(ctx: &GpuContext, scene: &Scene) -> Result<GpuScene, GpuError> {
        GpuScene::with_order(ctx, scene, TriangleOrder::MedianSplit)
    }

    /// [`GpuScene::new`] with the triangles handed to the BLAS builder in
    /// `order` (the AO is the same; the time to trace may not be).
    pub fn with_order(
        ctx: &GpuContext,
        scene: &Scene,
        order: TriangleOrder,
    ) -> Result<GpuScene, GpuError> {
        ctx.require_ray_queries()?;
        scene.validate()?;
        let limits = ctx.device.limits();
        for m in &scene.meshes {
            let tris = m.triangle_count() as u64;
            if tris > limits.max_blas_primitive_count as u64 {
                return Err(GpuError::Limits {
                    what: "triangles in one mesh",
                    needed: tris,
                    limit: limits.max_blas_primitive_count as u64,
                });
            }
        }
        // The TLAS instances' custom data (24 bits) carries the instance
        // index.
        if scene.instances.len() as u64 > 1 << 24 {
            return Err(GpuError::Limits {
                what: "instances (24-bit instance data)",
                needed: scene.instances.len() as u64,
                limit: 1 << 24,
            });
        }
        for m in &scene.meshes {
            let bytes = (m.positions.len() * 12).max(m.indices.len() * 4) as u64;
            if bytes > limits.max_buffer_size {
                return Err(GpuError::Limits {
                    what: "bytes of one mesh's vertices or indices",
                    needed: bytes,
                    limit: limits.max_buffer_size,
                });
            }
        }
        if scene.instances.len() as u64 > limits.max_tlas_instance_count as u64 {
            return Err(GpuError::Limits {
                what: "instances",
                needed: scene.instances.len() as u64,
                limit: limits.max_tlas_instance_count as u64,
            });
        }
        let skinned_instance = |i: usize| scene.deforms(i);
        let pose = scene.pose(0.0);
        let ordered: Vec<Vec<u32>> = scene
            .meshes
            .iter()
            .map(|m| match order {
                TriangleOrder::AsGiven => m.indices.clone(),
                TriangleOrder::MedianSplit => spatial_order(&m.positions, &m.indices),
            })
            .collect();
        // Per instance, the bounds of its local vertices (skinned at time 0
        // for a skinned instance, which `place` keeps current).
        let mesh_bounds: Vec<Bounds> = scene
            .meshes
            .iter()
            .map(|m| vertex_bounds(&m.positions))
            .collect();
        let mut local_bounds: Vec<Bounds> = scene
            .instances
            .iter()
            .map(|inst| mesh_bounds[inst.mesh])
            .collect();
        let (meshes, skinned) = ctx.checked("BLAS creation", || {
            let meshes: Vec<Option<MeshBlas>> = scene
                .meshes
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    let used_rigid = scene
                        .instances
                        .iter()
                        .enumerate()
                        .any(|(i, inst)| inst.mesh == k && !skinned_instance(i));
                    (used_rigid && m.triangle_count() > 0).then(|| {
                        MeshBlas::new(ctx, &m.positions, &ordered[k], false, m.alpha.is_none())
                    })
                })
                .collect();
            let skinned: Vec<Option<MeshBlas>> = (0..scene.instances.len())
                .map(|i| {
                    let m = &scene.meshes[scene.instances[i].mesh];
                    (skinned_instance(i) && m.triangle_count() > 0).then(|| {
                        let (p, _) = scene.deformed(i, &pose);
                        local_bounds[i] = vertex_bounds(&p);
                        let k = scene.instances[i].mesh;
                        MeshBlas::new(ctx, &p, &ordered[k], true, m.alpha.is_none())
                    })
                })
                .collect();
            (meshes, skinned)
        })?;
        let placed = (0..scene.instances.len())
            .filter(|&i| placed_blas(scene, &meshes, &skinned, i).is_some())
            .count();
        let tlas = (placed > 0).then(|| {
            ctx.device.create_tlas(&wgpu::CreateTlasDescriptor {
                label: Some("psao-gpu tlas"),
                max_instances: placed as u32,
                flags: wgpu::AccelerationStructureFlags::PREFER_FAST_TRACE,
                update_mode: wgpu::AccelerationStructureUpdateMode::Build,
            })
        });
        let mut s = GpuScene {
            meshes,
            skinned,
            tlas,
            alpha: AlphaTables::new(ctx, scene, &ordered)?,
            shape: Shape::of(scene),
            local_bounds,
            triangles: scene.meshes.iter().map(|m| m.triangle_count()).sum(),
            time: 0.0,
        };
        s.build(ctx, scene, &pose, true)?;
        Ok(s)
    }

    /// Poses the scene at time `t`: re-skins and rebuilds (or updates) the
    /// BLAS of every skinned instance and rebuilds the TLAS from the
    /// instances' transforms.
    pub fn pose(&mut self, ctx: &GpuContext, scene: &Scene, t: f32) -> Result<(), GpuError> {
        if !t.is_finite() {
            return Err(GpuError::Input(format!("time {t} is not finite")));
        }
        self.check_shape(scene)?;
        let pose = scene.pose(t);
        let skinned: Vec<Option<Vec<glam::Vec3>>> = (0..scene.instances.len())
            .map(|i| {
                self.skinned[i]
                    .is_some()
                    .then(|| scene.deformed(i, &pose).0.into_owned())
            })
            .collect();
        let vertices: Vec<Option<&[glam::Vec3]>> = skinned.iter().map(|v| v.as_deref()).collect();
        self.place(ctx, scene, &pose.instances, &vertices)?;
        self.time = t;
        Ok(())
    }

    /// Refuses a scene other than the one these structures were built for.
    fn check_shape(&self, scene: &Scene) -> Result<(), GpuError> {
        if Shape::of(scene) != self.shape {
            return Err(GpuError::Input(
                "the scene's meshes or instances are not those these acceleration structures were built for".into(),
            ));
        }
        Ok(())
    }

    /// Places the instances by `transforms` (one per instance of the
    /// scene this was made for) and, for a skinned instance, uploads
    /// `vertices[i]` (its current local vertex positions, the mesh's vertex
    /// count) before rebuilding its BLAS; then rebuilds the TLAS. This is
    /// what a server pipeline that animates the scene itself calls.
    pub fn place(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        transforms: &[glam::Affine3A],
        vertices: &[Option<&[glam::Vec3]>],
    ) -> Result<(), GpuError> {
        self.check_shape(scene)?;
        let n = scene.instances.len();
        if transforms.len() != n || vertices.len() != n || self.skinned.len() != n {
            return Err(GpuError::Input(format!(
                "{} transforms and {} vertex lists for {n} instances",
                transforms.len(),
                vertices.len()
            )));
        }
        if let Some(i) = transforms.iter().position(|t| {
            let det = t.matrix3.determinant();
            !t.is_finite() || !det.is_finite() || det.abs() <= f32::MIN_POSITIVE
        }) {
            return Err(GpuError::Input(format!(
                "instance {i}: transform is not finite or not invertible"
            )));
        }
        // None: the mesh's own positions.
        let skinned_vertices =
            |i: usize| vertices[i].unwrap_or(&scene.meshes[scene.instances[i].mesh].positions);
        // Every instance is checked before anything changes.
        for (i, slot) in self.skinned.iter().enumerate() {
            let Some(b) = slot else { continue };
            let v = skinned_vertices(i);
            if let Some(k) = v.iter().position(|p| !p.is_finite()) {
                return Err(GpuError::Input(format!(
                    "instance {i}: vertex {k} is not finite"
                )));
            }
            if v.len() as u32 != b.size.vertex_count {
                return Err(GpuError::Input(format!(
                    "instance {i}: {} vertices for a mesh of {}",
                    v.len(),
                    b.size.vertex_count
                )));
            }
        }
        for (i, slot) in self.skinned.iter().enumerate() {
            let Some(b) = slot else { continue };
            let v = skinned_vertices(i);
            self.local_bounds[i] = vertex_bounds(v);
            let flat: Vec<[f32; 3]> = v.iter().map(|p| p.to_array()).collect();
            ctx.queue
                .write_buffer(&b.vertices, 0, bytemuck::cast_slice(&flat));
        }
        self.build_with(ctx, scene, transforms, false)
    }

    /// Fills the TLAS from `pose` and builds it, with the mesh BLASes on
    /// the first build and the skinned ones every time.
    fn build(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        pose: &psao_scene::Pose,
        first: bool,
    ) -> Result<(), GpuError> {
        self.build_with(ctx, scene, &pose.instances, first)
    }

    /// Fills the TLAS from per-instance transforms and builds it.
    fn build_with(
        &mut self,
        ctx: &GpuContext,
        scene: &Scene,
        transforms: &[glam::Affine3A],
        first: bool,
    ) -> Result<(), GpuError> {
        let Some(tlas) = &mut self.tlas else {
            return Ok(());
        };
        let placed: Vec<(usize, &MeshBlas)> = (0..scene.instances.len())
            .filter_map(|i| placed_blas(scene, &self.meshes, &self.skinned, i).map(|b| (i, b)))
            .collect();
        // Instances in median-split order of their world bounds, like the
        // triangles of a BLAS.
        let boxes: Vec<Bounds> = placed
            .iter()
            .map(|&(i, _)| psao_scene::transformed_bounds(&transforms[i], self.local_bounds[i]))
            .collect();
        for (k, j) in median_split_order(&boxes).into_iter().enumerate() {
            let (i, blas) = placed[j];
            let m = transforms[i];
            let c = m.matrix3;
            let t = m.translation;
            // Row-major 3x4.
            let rows = [
                c.x_axis.x, c.y_axis.x, c.z_axis.x, t.x, c.x_axis.y, c.y_axis.y, c.z_axis.y, t.y,
                c.x_axis.z, c.y_axis.z, c.z_axis.z, t.z,
            ];
            tlas[k] = Some(wgpu::TlasInstance::new(&blas.blas, rows, i as u32, 0xFF));
        }
        let mut entries: Vec<wgpu::BlasBuildEntry<'_>> = Vec::new();
        if first {
            entries.extend(self.meshes.iter().flatten().map(MeshBlas::entry));
        }
        entries.extend(self.skinned.iter().flatten().map(MeshBlas::entry));
        let tlas = &*tlas;
        ctx.checked("acceleration structure build", || {
            let mut enc = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("psao-gpu build"),
                });
            enc.build_acceleration_structures(entries.iter(), std::iter::once(tlas));
            ctx.queue.submit(Some(enc.finish()));
        })?;
        ctx.wait()
    }

    /// The TLAS, if the scene has any triangle.
    pub(crate) fn tlas(&self) -> Option<&wgpu::Tlas> {
        self.tlas.as_ref()
    }

    /// The alpha tables.
    pub(crate) fn alpha(&self) -> &AlphaTables {
        &self.alpha
    }

    /// Triangles in the scene's meshes.
    pub fn triangles(&self) -> usize {
        self.triangles
    }

    /// The time the scene is posed at.
    pub fn time(&self) -> f32 {
        self.time
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// `n` random boxes of sizes from a millimetre to ten metres.
    fn boxes(n: usize, seed: u32) -> Vec<Bounds> {
        let u = |k: usize, j: u32| psao_scene::uniform(seed as u64, k as u32, j);
        (0..n)
            .map(|k| {
                let lo = Vec3::new(u(k, 0), u(k, 1), u(k, 2)) * 20.0;
                let size = Vec3::new(u(k, 3), u(k, 4), u(k, 5)).powf(4.0) * 10.0 + 1e-3;
                (lo, lo + size)
            })
            .collect()
    }

    /// The cost of splitting `items` at the median along `axis`.
    fn median_cost(b: &[Bounds], items: &[usize], axis: usize) -> f32 {
        let mut by_axis = items.to_vec();
        by_axis.sort_by(|&x, &y| centre(b, x, axis).total_cmp(&centre(b, y, axis)));
        let mid = items.len().div_ceil(2);
        half_area(union(b, &by_axis[..mid])) + half_area(union(b, &by_axis[mid..]))
    }

    /// Walks the tree lavapipe's builder (Mesa 25.0) makes over leaves
    /// `first..=last` of `order`: each node splits at `(first + last) / 2`,
    /// the first half ending there. Checks that every node's halves are
    /// those of a median split along an axis of least area: apart along
    /// that axis, with no other axis's median split cheaper.
    fn check_builder_tree(b: &[Bounds], order: &[usize], first: usize, last: usize) {
        if first >= last {
            return;
        }
        let split = (first + last) / 2;
        let (left, right) = (&order[first..=split], &order[split + 1..=last]);
        let items = &order[first..=last];
        let cost = half_area(union(b, left)) + half_area(union(b, right));
        let least = (0..3)
            .map(|axis| median_cost(b, items, axis))
            .fold(f32::INFINITY, f32::min);
        assert!(
            cost <= least,
            "leaves {first}..={last}: area {cost}, an axis gives {least}"
        );
        let apart = (0..3).any(|axis| {
            let l = left
                .iter()
                .map(|&i| centre(b, i, axis))
                .fold(f32::MIN, f32::max);
            let r = right
                .iter()
                .map(|&i| centre(b, i, axis))
                .fold(f32::MAX, f32::min);
            l <= r && median_cost(b, items, axis) == cost
        });
        assert!(
            apart,
            "leaves {first}..={last}: halves at {split} are no median split of least area"
        );
        check_builder_tree(b, order, first, split);
        check_builder_tree(b, order, split + 1, last);
    }

    #[test]
    fn the_tree_lavapipe_builds_over_the_order_is_the_median_split_tree_of_least_area() {
        for (seed, n) in [1, 2, 3, 5, 8, 17, 100, 1001].into_iter().enumerate() {
            let b = boxes(n, seed as u32);
            let order = median_split_order(&b);
            let mut seen = order.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..n).collect::<Vec<_>>(), "a permutation of {n}");
            check_builder_tree(&b, &order, 0, n - 1);
        }
    }

    #[test]
    fn splits_of_equal_area_go_along_the_widest_spread() {
        // Points on a line along y: every split has no area.
        let b: Vec<Bounds> = (0..9)
            .map(|k| {
                let p = Vec3::new(0.5, ((k * 4) % 9) as f32, 0.25);
                (p, p)
            })
            .collect();
        let mut all: Vec<usize> = (0..b.len()).collect();
        assert_eq!(best_split(&b, &mut all), 1);
        let order = median_split_order(&b);
        let first: Vec<f32> = order[..5].iter().map(|&i| b[i].0.y).collect();
        assert!(first.iter().all(|&y| y < 5.0), "first half {first:?}");
    }

    #[test]
    fn boxes_beyond_f32_area_still_split() {
        // Areas overflow to infinity (or NaN from inf * 0) on every axis.
        let big = Vec3::new(f32::MAX, f32::MAX, 0.0);
        let b: Vec<Bounds> = (0..6)
            .map(|k| (Vec3::new(-f32::MAX, k as f32, 0.0), big))
            .collect();
        let order = median_split_order(&b);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..6).collect::<Vec<_>>());
    }
}
