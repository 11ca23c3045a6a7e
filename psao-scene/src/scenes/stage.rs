//! Staging an imported model for streaming and benchmarks. An object gets
//! a floor under it (so it has something to occlude and be occluded by)
//! and, when the file has no camera path, a camera swinging round its
//! front. An
//! interior (a room whose faces point inward, seen from inside) gets no
//! floor (it has its own) and a camera that walks round inside it, looking
//! down across the room: from outside, a glTF renderer culls its walls' back
//! faces and little of it is seen.

use glam::{Affine3A, Vec3, Vec3A};
use obvhs::ray::Ray;

use crate::error::SceneError;
use crate::model::camera::{CameraKey, CameraPath};
use crate::model::mesh::{Mesh, bounds_of};
use crate::model::scene::Scene;
use crate::trace::geometry::{Geometry, TriangleBvh};

/// Margin around the model's bounds covered by the floor, in units of the
/// model's largest extent (a 7 cm car gets 7 cm of floor on each side, a
/// 155-unit fox 155 units): scale-free.
pub const FLOOR_MARGIN_EXTENTS: f32 = 1.0;

/// Azimuths [`stage`] weighs to find the side an object is meant to be
/// seen from.
pub const AZIMUTHS: usize = 16;

/// How far the staged orbit swings to either side of that side, radians
/// (45 degrees).
pub const SWING: f32 = std::f32::consts::FRAC_PI_4;

/// Seconds the staged camera takes for one loop of its path (a swing to
/// either side of an object's front and back, or a walk round a room).
pub const ORBIT_SECONDS: f32 = 20.0;

/// Rays cast from the centre of the bounds to tell an interior.
pub const PROBE_RAYS: usize = 256;

/// Share of [`PROBE_RAYS`] that must meet the front face of a surface for
/// the scene to be an interior.
pub const INTERIOR_SHARE: f32 = 0.75;

/// How the staged scene is meant to be seen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Setting {
    /// An object, seen from outside.
    Object,
    /// A room, seen from inside.
    Interior,
}

/// Whether `scene` (at time 0) is an object or an interior: an interior
/// when at least [`INTERIOR_SHARE`] of [`PROBE_RAYS`] rays from the centre
/// of its bounds meet the front face of a surface first. `None` for a
/// scene without triangles.
pub fn setting(scene: &Scene) -> Result<Option<Setting>, SceneError> {
    let tris = scene.world_triangles()?;
    let corners: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let Some((lo, hi)) = bounds_of(&corners) else {
        return Ok(None);
    };
    Ok(Some(setting_of(tris, (lo + hi) * 0.5)))
}

/// [`setting`] for world triangles and the probe's origin.
fn setting_of(tris: Vec<[Vec3; 3]>, centre: Vec3) -> Setting {
    if front_share(tris, centre) >= INTERIOR_SHARE {
        Setting::Interior
    } else {
        Setting::Object
    }
}

/// The share of [`PROBE_RAYS`] directions (a Fibonacci sphere) from
/// `from` whose first hit is a front face (counter-clockwise towards the
/// ray's origin).
pub fn front_share(tris: Vec<[Vec3; 3]>, from: Vec3) -> f32 {
    let normals: Vec<Vec3> = tris
        .iter()
        .map(|t| (t[1] - t[0]).cross(t[2] - t[0]))
        .collect();
    let bvh = TriangleBvh::new(Geometry {
        triangles: tris,
        masks: Vec::new(),
    });
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut front = 0;
    for k in 0..PROBE_RAYS {
        let z = 1.0 - 2.0 * (k as f32 + 0.5) / PROBE_RAYS as f32;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let a = golden * k as f32;
        let dir = Vec3::new(r * a.cos(), z, r * a.sin());
        let ray = Ray::new(Vec3A::from(from), Vec3A::from(dir), 0.0, f32::INFINITY);
        if let Some((t, _)) = bvh.closest_triangle(ray)
            && normals.get(t as usize).is_some_and(|n| n.dot(dir) < 0.0)
        {
            front += 1;
        }
    }
    front as f32 / PROBE_RAYS as f32
}

/// The azimuth (about +Y, from +X towards +Z, of the eye around the
/// centre) of the [`AZIMUTHS`] from which the most surface faces the
/// viewer: per triangle its area times the cosine towards the eye, front
/// faces only for single-sided materials (a mirrored instance's winding
/// flipped), either face for double-sided ones. Occlusion is not counted.
fn front_azimuth(scene: &Scene, tris: &[[Vec3; 3]]) -> f32 {
    // Per triangle, in world_triangles' order: the sign that turns its
    // winding normal into its front, 0 for double-sided.
    let pose = scene.pose(0.0);
    let mut signs = Vec::with_capacity(tris.len());
    for (i, inst) in scene.instances.iter().enumerate() {
        let sign = scene.front_sign(i, &pose.instances[i]);
        signs.extend(std::iter::repeat_n(
            sign,
            scene.meshes[inst.mesh].triangle_count(),
        ));
    }
    let best = (0..AZIMUTHS)
        .map(|k| {
            let a = std::f32::consts::TAU * k as f32 / AZIMUTHS as f32;
            let to_eye = Vec3::new(a.cos(), 0.35, a.sin()).normalize();
            let seen: f64 = tris
                .iter()
                .zip(&signs)
                .map(|(t, &sign)| {
                    let n = (t[1] - t[0]).cross(t[2] - t[0]) * 0.5;
                    let c = n.dot(to_eye);
                    (if sign == 0.0 {
                        c.abs()
                    } else {
                        (c * sign).max(0.0)
                    }) as f64
                })
                .sum();
            (k, seen)
        })
        .fold((0, f64::MIN), |b, x| if x.1 > b.1 { x } else { b });
    std::f32::consts::TAU * best.0 as f32 / AZIMUTHS as f32
}

/// Stages `scene` as [`setting`] finds it. An object gets a floor quad
/// (facing +Y) at the bottom of its bounds at rest, wider by
/// [`FLOOR_MARGIN_EXTENTS`] of its largest extent on each side, and, when
/// the scene has no camera path, a camera that swings [`SWING`] to either
/// side of the object's front (the side most of its surface faces, see
/// `front_azimuth`) and back in [`ORBIT_SECONDS`], looking slightly down
/// from where the model's box fills the view. An interior gets no floor and,
/// without a camera path, a camera circling inside in [`ORBIT_SECONDS`]
/// at mid height, 60% of the way from the centre to the walls, looking
/// down across the middle of the room (its floor and what stands there)
/// at the far side.
/// A scene without triangles is an error.
pub fn stage(mut scene: Scene) -> Result<Scene, SceneError> {
    let tris = scene.world_triangles()?;
    let corners: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let Some((lo, hi)) = bounds_of(&corners) else {
        return Err(SceneError::Camera {
            reason: "the scene has no triangles to stage".into(),
        });
    };
    let centre = (lo + hi) * 0.5;
    let half = (hi - lo) * 0.5;
    let front = front_azimuth(&scene, &tris);
    let setting = setting_of(tris, centre);
    if setting == Setting::Object {
        let margin = (hi - lo).max_element() * FLOOR_MARGIN_EXTENTS;
        let (flo, fhi) = (lo - Vec3::splat(margin), hi + Vec3::splat(margin));
        let size = fhi - flo;
        scene.add(
            Mesh::quad(
                Vec3::new(flo.x, lo.y, flo.z),
                Vec3::Z * size.z,
                Vec3::X * size.x,
            )
            .subdivided(2),
            Affine3A::IDENTITY,
        );
    }
    if scene.camera.is_none() {
        let steps = 8;
        let keys = (0..=steps)
            .map(|k| {
                let a = std::f32::consts::TAU * k as f32 / steps as f32;
                let (c, s) = (a.cos(), a.sin());
                let (eye, target) = match setting {
                    Setting::Object => {
                        // Swinging to and fro about the front, far enough
                        // that the model's box (its widest horizontal
                        // diagonal, or its height) fills the 50-degree view.
                        let swing = front + SWING * a.sin();
                        let (c, s) = (swing.cos(), swing.sin());
                        let size = Vec3::new(half.x, 0.0, half.z).length().max(half.y);
                        let reach = size.max(1e-3) / 25f32.to_radians().tan() * 1.15;
                        (
                            centre + Vec3::new(c * reach, half.y + reach * 0.35, s * reach),
                            centre - Vec3::Y * (half.y * 0.3),
                        )
                    }
                    Setting::Interior => (
                        centre + Vec3::new(c * half.x * 0.6, 0.0, s * half.z * 0.6),
                        centre + Vec3::new(-c * half.x * 0.2, -half.y * 0.6, -s * half.z * 0.2),
                    ),
                };
                CameraKey {
                    time: ORBIT_SECONDS * k as f32 / steps as f32,
                    eye,
                    target,
                }
            })
            .collect();
        scene.camera = Some(CameraPath {
            keys,
            fov_y: 50f32.to_radians(),
        });
    }
    scene.validate()?;
    Ok(scene)
}
