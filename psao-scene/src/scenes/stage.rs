//! Staging an imported model for streaming and benchmarks: a floor under
//! it (so it has something to occlude and be occluded by) and, when the
//! file has no camera path, a camera orbiting it.

use glam::{Affine3A, Vec3};

use crate::error::SceneError;
use crate::model::camera::{CameraKey, CameraPath};
use crate::model::mesh::{Mesh, bounds_of};
use crate::model::scene::Scene;

/// Margin around the model's bounds covered by the floor, in scene units.
pub const FLOOR_MARGIN: f32 = 2.0;

/// Seconds the staged camera takes for one orbit.
pub const ORBIT_SECONDS: f32 = 20.0;

/// Adds a floor quad (facing +Y) at the bottom of the scene's bounds at
/// rest, [`FLOOR_MARGIN`] wider on each side; and, when the scene has no
/// camera path, a camera orbiting the bounds' centre once in
/// [`ORBIT_SECONDS`] at 2.4 times the bounds' half-diagonal, looking
/// slightly down.
/// A scene without triangles is an error.
pub fn stage(mut scene: Scene) -> Result<Scene, SceneError> {
    let tris = scene.world_triangles()?;
    let corners: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let Some((lo, hi)) = bounds_of(&corners) else {
        return Err(SceneError::Camera {
            reason: "the scene has no triangles to stage".into(),
        });
    };
    let (flo, fhi) = (
        lo - Vec3::splat(FLOOR_MARGIN),
        hi + Vec3::splat(FLOOR_MARGIN),
    );
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
    if scene.camera.is_none() {
        let centre = (lo + hi) * 0.5;
        let half = (hi - lo) * 0.5;
        // Far enough that the whole model stays in view at 50 degrees.
        let reach = half.length().max(1e-3) * 2.4;
        let steps = 8;
        let keys = (0..=steps)
            .map(|k| {
                let a = std::f32::consts::TAU * k as f32 / steps as f32;
                CameraKey {
                    time: ORBIT_SECONDS * k as f32 / steps as f32,
                    eye: centre
                        + Vec3::new(a.cos() * reach, half.y + reach * 0.35, a.sin() * reach),
                    target: centre - Vec3::Y * (half.y * 0.3),
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
