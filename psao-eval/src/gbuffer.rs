//! The scene posed at one moment ([`PosedScene`]) and its G-buffer from
//! primary rays ([`GBuffer`]): per pixel the world position, the shading
//! normal, the instance hit and the depth. Every per-pixel AO pass (the
//! ray-traced reference, the PSAO client image, SAO, RTAO at a few rays per
//! pixel) reads the same G-buffer, so their images differ only by the AO
//! method.

use std::sync::Arc;

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::ray::Ray;
use rayon::prelude::*;

use crate::view::View;
use psao_scene::{
    AoTracer, Geometry, Layer, Scene, SceneError, TriangleBvh, barycentric, normal_matrix,
};

/// The instance id of a pixel where no geometry was hit.
pub const NO_INSTANCE: u32 = u32::MAX;

/// Every triangle of a scene posed at one time, in world space, in one BVH,
/// with the instance and triangle each came from and its world vertex
/// normals.
#[derive(Clone, Debug)]
pub struct PosedScene {
    bvh: Arc<TriangleBvh>,
    /// Per world triangle: (instance, triangle in the instance's mesh).
    owners: Vec<(u32, u32)>,
    /// Per world triangle: its world corners.
    corners: Vec<[Vec3; 3]>,
    /// Per world triangle: the unit world normals at its corners.
    normals: Vec<[Vec3; 3]>,
    /// Per world triangle: its corners and their normals as its mesh
    /// stores them, undeformed (the bind space of point format 1).
    bind: Vec<[Vec3; 3]>,
    bind_normals: Vec<[Vec3; 3]>,
    /// Per world triangle: 0 when its mesh is double-sided, else the sign
    /// of its instance's determinant (+1 or -1): its front face is the
    /// side its world corners wind counterclockwise around, flipped by a
    /// mirroring transform (as glTF says).
    facing: Vec<i8>,
    /// Per instance: its local-to-world transform at this time.
    transforms: Vec<Affine3A>,
    time: f32,
}

impl PosedScene {
    /// Poses `scene` at time `t` (animations, skins) and builds a BVH over
    /// all its triangles. The scene is validated first; a pose whose
    /// transforms or skinned vertices are not finite is an error naming the
    /// instance.
    pub fn new(scene: &Scene, t: f32) -> Result<PosedScene, SceneError> {
        scene.validate()?;
        if !t.is_finite() {
            return Err(SceneError::Parameter {
                name: "time",
                value: t as f64,
                rule: "finite",
            });
        }
        let pose = scene.pose(t);
        let masks: Vec<_> = scene
            .meshes
            .iter()
            .map(|m| m.alpha.clone().map(Arc::new))
            .collect();
        let mut g = Geometry::default();
        let (mut owners, mut normals, mut facing) = (Vec::new(), Vec::new(), Vec::new());
        let (mut bind, mut bind_normals) = (Vec::new(), Vec::new());
        for (i, inst) in scene.instances.iter().enumerate() {
            let to_world = pose.instances[i];
            let det = to_world.matrix3.determinant();
            if !to_world.is_finite() || !det.is_finite() || det.abs() <= f32::MIN_POSITIVE {
                return Err(SceneError::BadTransform { instance: i });
            }
            let nm = normal_matrix(&to_world);
            let mesh = &scene.meshes[inst.mesh];
            let front = scene.front_sign(i, &to_world);
            let (pos, nrm) = scene.deformed(i, &pose);
            let world: Vec<Vec3> = pos.iter().map(|&p| to_world.transform_point3(p)).collect();
            if let Some(v) = world.iter().position(|p| !p.is_finite()) {
                return Err(SceneError::NonFiniteVertex {
                    mesh: inst.mesh,
                    vertex: v,
                });
            }
            for tri in 0..mesh.triangle_count() {
                let idx = [
                    mesh.indices[3 * tri],
                    mesh.indices[3 * tri + 1],
                    mesh.indices[3 * tri + 2],
                ];
                g.triangles.push(idx.map(|k| world[k as usize]));
                g.masks.push(masks[inst.mesh].clone().map(|m| (m, idx)));
                normals.push(idx.map(|k| (nm * nrm[k as usize]).normalize_or_zero()));
                bind.push(idx.map(|k| mesh.positions[k as usize]));
                bind_normals.push(idx.map(|k| mesh.normals[k as usize].normalize_or_zero()));
                owners.push((i as u32, tri as u32));
                facing.push(front as i8);
            }
        }
        let corners = g.triangles.clone();
        Ok(PosedScene {
            bvh: Arc::new(TriangleBvh::new(g)),
            owners,
            corners,
            normals,
            bind,
            bind_normals,
            facing,
            transforms: pose.instances,
            time: t,
        })
    }

    /// The time the scene was posed at.
    pub fn time(&self) -> f32 {
        self.time
    }

    /// Number of triangles.
    pub fn triangles(&self) -> usize {
        self.owners.len()
    }

    /// Instance `i`'s local-to-world transform at this time.
    pub fn transform(&self, i: usize) -> Option<Affine3A> {
        self.transforms.get(i).copied()
    }

    /// An AO tracer over this geometry (the same BVH, shared).
    pub fn tracer(&self) -> AoTracer {
        AoTracer::from_layers(vec![Layer::world(self.bvh.clone())])
    }

    /// Casts one primary ray through the centre of every pixel of `view`
    /// (rows in parallel) and records what it hits.
    pub fn gbuffer(&self, view: &View) -> GBuffer {
        let to_world = self.view_to_world(view);
        let eye = view.camera.eye;
        let w = view.width as usize;
        let mut g = GBuffer::empty(view);
        let rows: Vec<Vec<Option<Sample>>> = (0..view.height)
            .into_par_iter()
            .map(|py| {
                (0..view.width)
                    .map(|px| self.primary(view, &to_world, eye, px, py))
                    .collect()
            })
            .collect();
        for (py, row) in rows.into_iter().enumerate() {
            for (px, s) in row.into_iter().enumerate() {
                let k = py * w + px;
                if let Some(s) = s {
                    g.position[k] = s.position;
                    g.normal[k] = s.normal;
                    g.bind_position[k] = s.bind_position;
                    g.bind_normal[k] = s.bind_normal;
                    g.instance[k] = s.instance;
                    g.depth[k] = s.depth;
                }
            }
        }
        g
    }

    /// View-to-world transform of `view`.
    fn view_to_world(&self, view: &View) -> Affine3A {
        view.world_to_view().inverse()
    }

    /// The hit of the primary ray of pixel `(px, py)`.
    fn primary(
        &self,
        view: &View,
        to_world: &Affine3A,
        eye: Vec3,
        px: u32,
        py: u32,
    ) -> Option<Sample> {
        let d_view = view.view_dir(px, py);
        let dir = to_world.transform_vector3(d_view);
        let len = dir.length();
        let unit = dir / len;
        // The nearest face the camera sees: a single-sided face seen from
        // behind is culled, as a glTF renderer culls it (doubleSided:
        // false), and the ray goes on past it.
        let mut tmin = 0.0f32;
        let (prim, t) = loop {
            let ray = Ray::new(Vec3A::from(eye), Vec3A::from(unit), tmin, f32::INFINITY);
            let (prim, t) = self.bvh.closest_triangle(ray)?;
            if !self.culled(prim as usize, unit) {
                break (prim, t);
            }
            let next = t + t.abs() * 4e-7 + f32::MIN_POSITIVE;
            if next <= tmin || !next.is_finite() {
                return None;
            }
            tmin = next;
        };
        let [a, b, c] = self.corners[prim as usize];
        let hit = eye + unit * t;
        let w = barycentric(hit, a, b, c);
        // The interpolated point lies on the triangle's plane, which keeps
        // AO rays from starting below the surface far from the origin.
        let position = a * w[0] + b * w[1] + c * w[2];
        let [na, nb, nc] = self.normals[prim as usize];
        let mut normal = (na * w[0] + nb * w[1] + nc * w[2]).normalize_or_zero();
        if normal == Vec3::ZERO {
            normal = (b - a).cross(c - a).normalize_or_zero();
        }
        // The same surface point in bind space: the undeformed corners with
        // the same barycentrics, as a rasterizer interpolates an attribute.
        let [ba, bb, bc] = self.bind[prim as usize];
        let bind_position = ba * w[0] + bb * w[1] + bc * w[2];
        let [bna, bnb, bnc] = self.bind_normals[prim as usize];
        let mut bind_normal = (bna * w[0] + bnb * w[1] + bnc * w[2]).normalize_or_zero();
        if bind_normal == Vec3::ZERO {
            bind_normal = (bb - ba).cross(bc - ba).normalize_or_zero();
        }
        // Shade the side the camera sees, told by the triangle's face as a
        // rasterizer's front-facing test is, not by the interpolated
        // normal, which at a grazing silhouette can point away from a face
        // that faces the camera: flipping it there turned the normal into
        // the surface (the reference then traced into the mesh, dark, where
        // no point faces that way). A single-sided face the camera sees is
        // its front (its back is culled): never flipped. A double-sided one
        // flips when the camera is on the other side of its plane from its
        // vertex normals.
        let face = (b - a).cross(c - a);
        let face = if face.dot(normal) < 0.0 { -face } else { face };
        if self.facing[prim as usize] == 0 && face.dot(unit) > 0.0 {
            normal = -normal;
            bind_normal = -bind_normal;
        }
        Some(Sample {
            position,
            normal,
            bind_position,
            bind_normal,
            instance: self.owners[prim as usize].0,
            // Distance along the view axis (the view direction has z = -1).
            depth: t / len,
        })
    }
}

impl PosedScene {
    /// Whether world triangle `prim` is single-sided and `dir` sees its
    /// back.
    fn culled(&self, prim: usize, dir: Vec3) -> bool {
        let sign = self.facing[prim];
        if sign == 0 {
            return false;
        }
        let [a, b, c] = self.corners[prim];
        let front = (b - a).cross(c - a) * sign as f32;
        front.dot(dir) > 0.0
    }
}

/// What a primary ray hit.
struct Sample {
    position: Vec3,
    normal: Vec3,
    bind_position: Vec3,
    bind_normal: Vec3,
    instance: u32,
    depth: f32,
}

/// Per-pixel surface attributes of one view (row-major, top row first).
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// World position of the surface seen (zero where nothing was hit).
    pub position: Vec<Vec3>,
    /// Unit world shading normal, on the camera's side of the surface (a
    /// double-sided face seen from behind has its normals flipped; zero
    /// where nothing was hit).
    pub normal: Vec<Vec3>,
    /// The surface's position in its mesh's bind space: the undeformed
    /// vertices interpolated as the deformed ones are (zero where nothing
    /// was hit). Point format 1 instances are looked up with it.
    pub bind_position: Vec<Vec3>,
    /// The bind-space normal, facing as [`Self::normal`] does (zero where
    /// nothing was hit).
    pub bind_normal: Vec<Vec3>,
    /// The instance seen, or [`NO_INSTANCE`].
    pub instance: Vec<u32>,
    /// Distance along the view axis (`f32::INFINITY` where nothing was
    /// hit), as SAO's depth buffer.
    pub depth: Vec<f32>,
}

impl GBuffer {
    /// A G-buffer of `view`'s size where nothing was hit.
    pub fn empty(view: &View) -> GBuffer {
        let n = view.pixels();
        GBuffer {
            width: view.width,
            height: view.height,
            position: vec![Vec3::ZERO; n],
            normal: vec![Vec3::ZERO; n],
            bind_position: vec![Vec3::ZERO; n],
            bind_normal: vec![Vec3::ZERO; n],
            instance: vec![NO_INSTANCE; n],
            depth: vec![f32::INFINITY; n],
        }
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.instance.len()
    }

    /// Number of pixels that see geometry.
    pub fn covered(&self) -> usize {
        self.instance.iter().filter(|&&i| i != NO_INSTANCE).count()
    }

    /// Checks that every attribute holds `width x height` values (the
    /// fields are public, so a caller may have changed them).
    pub fn check(&self) -> Result<(), SceneError> {
        let n = self.width as u64 * self.height as u64;
        let lens = [
            ("position", self.position.len()),
            ("normal", self.normal.len()),
            ("bind position", self.bind_position.len()),
            ("bind normal", self.bind_normal.len()),
            ("instance", self.instance.len()),
            ("depth", self.depth.len()),
        ];
        match lens.iter().find(|(_, len)| *len as u64 != n) {
            Some((name, len)) => Err(SceneError::Parameter {
                name: "G-buffer length",
                value: *len as f64,
                rule: match *name {
                    "position" => "positions must number width x height",
                    "normal" => "normals must number width x height",
                    "bind position" => "bind positions must number width x height",
                    "bind normal" => "bind normals must number width x height",
                    "instance" => "instance ids must number width x height",
                    _ => "depths must number width x height",
                },
            }),
            None => Ok(()),
        }
    }
}
