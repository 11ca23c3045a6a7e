//! Staging an imported model for streaming and benchmarks. An object gets
//! a floor under it (so it has something to occlude and be occluded by)
//! and, when the file has no camera path, a camera orbiting it. An
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

/// Margin around the model's bounds covered by the floor, in scene units,
/// at most [`FLOOR_MARGIN_EXTENTS`] times the model's largest extent (a
/// 7 cm model gets a floor of its own size, not metres of it).
pub const FLOOR_MARGIN: f32 = 2.0;

/// The floor margin's cap, in units of the model's largest extent.
pub const FLOOR_MARGIN_EXTENTS: f32 = 1.5;

/// Seconds the staged camera takes for one orbit.
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

/// Stages `scene` as [`setting`] finds it. An object gets a floor quad
/// (facing +Y) at the bottom of its bounds at rest, [`FLOOR_MARGIN`] wider
/// on each side (capped at [`FLOOR_MARGIN_EXTENTS`] of its largest
/// extent), and, when the scene has no camera path, a camera orbiting the
/// bounds' centre once in [`ORBIT_SECONDS`] at 2.4 times the bounds'
/// half-diagonal, looking slightly down. An interior gets no floor and,
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
    let setting = setting_of(tris, centre);
    if setting == Setting::Object {
        let margin = FLOOR_MARGIN.min((hi - lo).max_element() * FLOOR_MARGIN_EXTENTS);
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
                        // Far enough that the whole model stays in view
                        // at 50 degrees.
                        let reach = half.length().max(1e-3) * 2.4;
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
