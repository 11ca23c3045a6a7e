//! The embedded default scene: built in code, no file needed.
//!
//! A 12 m courtyard: floor, three walls, four columns, three steps, a table
//! and a bench, a thin railing (posts and a 4 cm rail, the case screen-space
//! AO gets wrong), a box sliding back and forth next to the table (rigid
//! motion close to static surfaces), and a large static area in the far
//! half that nothing reaches. (A skinned character comes with the skinning
//! slice of issue 3.)

use glam::{Affine3A, Vec3};

use crate::pipeline::Motion;
use crate::scene::{Mesh, Scene};

/// Index of the sliding box among the default scene's instances.
pub const MOVING_BOX: usize = 14;

/// The default scene and the motion of each instance.
pub fn default_scene() -> (Scene, Vec<Motion>) {
    let mut s = Scene::default();
    let id = Affine3A::IDENTITY;
    // Floor and walls, subdivided so large faces hold many triangles.
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::Z * 12.0, Vec3::X * 12.0).subdivided(3),
        id,
    );
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::X * 12.0, Vec3::Y * 3.0).subdivided(2),
        id,
    );
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::Y * 3.0, Vec3::Z * 12.0).subdivided(2),
        id,
    );
    s.add(
        Mesh::quad(Vec3::new(12.0, 0.0, 0.0), Vec3::Z * 12.0, Vec3::Y * 3.0).subdivided(2),
        id,
    );
    for (x, z) in [(3.0, 3.0), (9.0, 3.0), (3.0, 9.0), (9.0, 9.0)] {
        let column = Mesh::cuboid(Vec3::new(-0.2, 0.0, -0.2), Vec3::new(0.2, 3.0, 0.2));
        s.add(column, Affine3A::from_translation(Vec3::new(x, 0.0, z)));
    }
    // Steps along the back wall.
    for k in 0..3 {
        let h = 0.15 * (k + 1) as f32;
        let z0 = 0.3 * k as f32;
        s.add(
            Mesh::cuboid(Vec3::new(4.0, 0.0, z0), Vec3::new(8.0, h, z0 + 0.3)),
            id,
        );
    }
    // Table and bench.
    s.add(
        Mesh::cuboid(Vec3::new(5.0, 0.0, 5.0), Vec3::new(6.5, 0.75, 6.0)),
        id,
    );
    s.add(
        Mesh::cuboid(Vec3::new(5.0, 0.0, 6.4), Vec3::new(6.5, 0.45, 6.8)),
        id,
    );
    // Railing: a thin rail on posts.
    let mut railing = Mesh::cuboid(Vec3::new(1.0, 0.9, 1.5), Vec3::new(11.0, 0.94, 1.54));
    for k in 0..6 {
        let x = 1.0 + 2.0 * k as f32;
        let post = Mesh::cuboid(Vec3::new(x, 0.0, 1.5), Vec3::new(x + 0.04, 0.9, 1.54));
        let base = railing.positions.len() as u32;
        railing.positions.extend(post.positions);
        railing.normals.extend(post.normals);
        railing
            .indices
            .extend(post.indices.iter().map(|i| base + i));
    }
    s.add(railing, id);
    // The sliding box (instance MOVING_BOX), 0.5 m, resting on the floor.
    let moving = s.add(Mesh::cuboid(Vec3::splat(-0.25), Vec3::splat(0.25)), id);
    let mut motions: Vec<Motion> = (0..s.instances.len()).map(|_| None).collect();
    motions[moving] = Some(Box::new(|t: f32| {
        // Back and forth along x beside the table, period 8 s.
        let phase = (t / 8.0).fract();
        let u = if phase < 0.5 {
            phase * 2.0
        } else {
            2.0 - phase * 2.0
        };
        Affine3A::from_translation(Vec3::new(3.5 + 4.0 * u, 0.25, 4.4))
    }));
    (s, motions)
}
