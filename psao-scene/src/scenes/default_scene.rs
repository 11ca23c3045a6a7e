//! The embedded default scene: built in code, no file needed (the
//! character is compiled in).
//!
//! A 12 m courtyard: floor, three walls, four columns, three steps, a table
//! and a bench, a thin railing (posts and a 4 cm rail, the case screen-space
//! AO gets wrong), an alpha-masked trellis screen (holes that neither
//! points nor rays may see as surface), a box sliding back and forth next
//! to the table (rigid motion close to static surfaces), a skinned
//! character (CesiumMan) walking back and forth between the columns, and a
//! large static area in the far half that nothing reaches. A camera path
//! of 20 s walks the viewer around the courtyard.

use std::f32::consts::FRAC_PI_2;

use glam::{Affine3A, Quat, Vec2, Vec3};

use crate::import::load_gltf_slice;
use crate::model::alpha::{AlphaMask, AlphaTexture};
use crate::model::animation::{Animation, Channel, Interpolation, Keys};
use crate::model::camera::{CameraKey, CameraPath};
use crate::model::mesh::Mesh;
use crate::model::node::Trs;
use crate::model::scene::Scene;

/// Index of the sliding box among the default scene's instances.
pub const MOVING_BOX: usize = 14;

/// Index of the alpha-masked trellis among the default scene's instances.
pub const TRELLIS: usize = 15;

/// Index of the skinned character's (first) instance in the default scene.
pub const WALKER: usize = 16;

/// CesiumMan (CC-BY 4.0, Cesium; see `assets/README.md`).
pub(crate) const CESIUM_MAN: &[u8] = include_bytes!("../../assets/CesiumMan.glb");

/// The default scene.
pub fn default_scene() -> Scene {
    let mut s = static_courtyard();
    // The sliding box (instance MOVING_BOX), 0.5 m, resting on the floor,
    // back and forth along x beside the table, period 8 s.
    let node = s.add_node("sliding box", None, Trs::default());
    let moving = s.add_on_node(Mesh::cuboid(Vec3::splat(-0.25), Vec3::splat(0.25)), node);
    debug_assert_eq!(moving, MOVING_BOX);
    s.animations.push(Animation::translation(
        "slide",
        node,
        &[
            (0.0, Vec3::new(3.5, 0.25, 4.4)),
            (4.0, Vec3::new(7.5, 0.25, 4.4)),
            (8.0, Vec3::new(3.5, 0.25, 4.4)),
        ],
    ));
    let trellis = s.add(trellis(), Affine3A::IDENTITY);
    debug_assert_eq!(trellis, TRELLIS);
    add_walker(&mut s);
    s.camera = Some(camera_path());
    s
}

/// The benchmark's skinned scene: CesiumMan alone, walking in place,
/// staged on a floor with a camera orbiting it ([`stage`](crate::stage)).
pub fn cesium_man_scene() -> Scene {
    let man = load_gltf_slice(CESIUM_MAN, "CesiumMan.glb", None)
        .expect("the embedded CesiumMan model loads");
    crate::scenes::stage::stage(man).expect("the embedded CesiumMan model stages")
}

/// The static part: floor, walls, columns, steps, table, bench, railing.
fn static_courtyard() -> Scene {
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
    s
}

/// A 2 m x 2 m double-sided screen standing against the right wall, alpha
/// masked into a lattice: 8 cm bars every 25 cm, holes between.
fn trellis() -> Mesh {
    let mut m = Mesh::quad(Vec3::new(11.4, 0.0, 4.0), Vec3::Y * 2.0, Vec3::Z * 2.0);
    m.double_sided = true;
    const N: u32 = 32;
    let alpha = (0..N * N)
        .map(|i| {
            let (x, y) = (i % N, i / N);
            if x < 10 || y < 10 { 255 } else { 0 }
        })
        .collect();
    // The texture repeats 8 times over 2 m: one lattice period per 25 cm.
    let uvs = m
        .positions
        .iter()
        .map(|p| Vec2::new(p.y, p.z - 4.0) * 4.0)
        .collect();
    m.alpha = Some(AlphaMask {
        cutoff: 0.5,
        factor: 1.0,
        vertex_alpha: Vec::new(),
        texture: Some(AlphaTexture {
            uvs,
            width: N,
            height: N,
            alpha,
        }),
    });
    m
}

/// CesiumMan walking back and forth along z = 7.6 between x = 2 and
/// x = 10, turning at each end; period 18 s.
fn add_walker(s: &mut Scene) {
    let man = load_gltf_slice(CESIUM_MAN, "CesiumMan.glb", None)
        .expect("the embedded CesiumMan model loads");
    let root = s.add_node("walker", None, Trs::default());
    let range = s.append(man, Some(root));
    debug_assert_eq!(range.start, WALKER);
    let (z, y) = (7.6, 0.0);
    let yaw = |a: f32| Quat::from_rotation_y(a);
    let times = vec![0.0, 8.0, 8.5, 9.0, 17.0, 17.5, 18.0];
    s.animations.push(Animation {
        name: "walk path".into(),
        channels: vec![
            Channel {
                node: root,
                times: times.clone(),
                keys: Keys::Translation(vec![
                    Vec3::new(2.0, y, z),
                    Vec3::new(10.0, y, z),
                    Vec3::new(10.0, y, z),
                    Vec3::new(10.0, y, z),
                    Vec3::new(2.0, y, z),
                    Vec3::new(2.0, y, z),
                    Vec3::new(2.0, y, z),
                ]),
                interpolation: Interpolation::Linear,
            },
            Channel {
                node: root,
                times,
                keys: Keys::Rotation(
                    [0.0, 0.0, 1.0, 2.0, 2.0, 3.0, 4.0]
                        .map(|k| yaw(WALKER_FACING + k * FRAC_PI_2))
                        .to_vec(),
                ),
                interpolation: Interpolation::Linear,
            },
        ],
    });
}

/// Yaw that turns the character (modelled facing +z) to face +x.
const WALKER_FACING: f32 = FRAC_PI_2;

/// 20 s around the courtyard at eye height, looking at its middle.
fn camera_path() -> CameraPath {
    let key = |time: f32, eye: Vec3, target: Vec3| CameraKey { time, eye, target };
    let look = Vec3::new(6.0, 0.8, 6.0);
    CameraPath {
        keys: vec![
            key(0.0, Vec3::new(6.0, 1.7, 11.5), look),
            key(5.0, Vec3::new(1.0, 1.7, 10.5), look),
            key(10.0, Vec3::new(1.0, 2.2, 6.0), Vec3::new(7.0, 0.5, 7.0)),
            key(15.0, Vec3::new(6.0, 2.5, 11.0), Vec3::new(9.0, 0.5, 5.0)),
            key(20.0, Vec3::new(11.0, 1.7, 10.5), look),
        ],
        fov_y: 60f32.to_radians(),
    }
}
