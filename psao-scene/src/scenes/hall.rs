//! A procedural hall: the bench set's large interior with many moving
//! parts, built in code from the embedded CesiumMan and boxes.
//!
//! A 36 m x 18 m hall, 6 m high, its floor, ceiling and walls facing
//! inward; two rows of pillars; rows of tables; [`HallParams::props`]
//! boxes sliding back and forth across the floor and the tables, each on
//! its own node with its own period (one shared mesh); and
//! [`HallParams::figures`] CesiumMan figures walking up and down the
//! aisles. A camera path of 30 s walks the length of the hall at eye
//! height. It measures what many moving instances and millions of points
//! cost (1.28 million points at 1024 spawned per m^2, the bench's N = 512;
//! 5.1 million at 4096, N = 2048).

use glam::{Affine3A, Quat, Vec3};

use crate::import::load_gltf_slice;
use crate::model::animation::{Animation, Channel, Interpolation, Keys};
use crate::model::camera::{CameraKey, CameraPath};
use crate::model::mesh::Mesh;
use crate::model::node::Trs;
use crate::model::scene::{Instance, Scene};

/// Hall length along x, m.
const LENGTH: f32 = 36.0;
/// Hall width along z, m.
const WIDTH: f32 = 18.0;
/// Hall height, m.
const HEIGHT: f32 = 6.0;

/// What the hall holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HallParams {
    /// Moving boxes (each its own instance and node).
    pub props: usize,
    /// Walking CesiumMan figures (each its own skinned instance).
    pub figures: usize,
}

impl Default for HallParams {
    fn default() -> Self {
        HallParams {
            props: 160,
            figures: 4,
        }
    }
}

/// The hall with [`HallParams::default`].
pub fn hall_scene() -> Scene {
    hall(HallParams::default())
}

/// The hall holding `params`.
pub fn hall(params: HallParams) -> Scene {
    let mut s = Scene::default();
    let id = Affine3A::IDENTITY;
    let (l, w, h) = (LENGTH, WIDTH, HEIGHT);
    // A quad's normal is u x v: floor up, ceiling down, walls inward.
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::Z * w, Vec3::X * l).subdivided(4),
        id,
    );
    s.add(
        Mesh::quad(Vec3::new(0.0, h, 0.0), Vec3::X * l, Vec3::Z * w).subdivided(4),
        id,
    );
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::X * l, Vec3::Y * h).subdivided(3),
        id,
    );
    s.add(
        Mesh::quad(Vec3::new(0.0, 0.0, w), Vec3::Y * h, Vec3::X * l).subdivided(3),
        id,
    );
    s.add(
        Mesh::quad(Vec3::ZERO, Vec3::Y * h, Vec3::Z * w).subdivided(3),
        id,
    );
    s.add(
        Mesh::quad(Vec3::new(l, 0.0, 0.0), Vec3::Z * w, Vec3::Y * h).subdivided(3),
        id,
    );
    // Pillars: two rows of eight, one shared mesh.
    let pillar = s.add(
        Mesh::cuboid(Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, h, 0.3)),
        Affine3A::from_translation(pillar_at(0, 0)),
    );
    let pillar_mesh = s.instances[pillar].mesh;
    for row in 0..2 {
        for k in 0..8 {
            if (row, k) != (0, 0) {
                place(
                    &mut s,
                    pillar_mesh,
                    Affine3A::from_translation(pillar_at(row, k)),
                );
            }
        }
    }
    // Tables: three rows of seven, one shared mesh (a top on a block).
    let first = s.add(hall_table(), Affine3A::from_translation(table_at(0, 0)));
    let table_mesh = s.instances[first].mesh;
    for row in 0..3 {
        for k in 0..7 {
            if (row, k) != (0, 0) {
                place(
                    &mut s,
                    table_mesh,
                    Affine3A::from_translation(table_at(row, k)),
                );
            }
        }
    }
    add_props(&mut s, params.props);
    add_figures(&mut s, params.figures);
    s.camera = Some(camera_path());
    s
}

/// Adds an instance of mesh `mesh` placed by `transform`.
fn place(s: &mut Scene, mesh: usize, transform: Affine3A) {
    s.instances.push(Instance {
        mesh,
        transform,
        node: None,
        skin: None,
    });
}

fn pillar_at(row: usize, k: usize) -> Vec3 {
    Vec3::new(2.0 + 4.6 * k as f32, 0.0, if row == 0 { 4.5 } else { 13.5 })
}

fn table_at(row: usize, k: usize) -> Vec3 {
    Vec3::new(4.3 + 4.6 * k as f32, 0.0, [2.2, 9.0, 15.8][row])
}

/// A number in [0, 1) from `k` and `salt` (deterministic).
fn unit(k: usize, salt: u32) -> f32 {
    crate::random::uniform(0x4841_4c4c, k as u32, salt)
}

/// `n` 0.4 m boxes, each on its own node, sliding back and forth along x
/// (on the floor or on a table top) with its own period and phase.
fn add_props(s: &mut Scene, n: usize) {
    let mut mesh = None;
    for k in 0..n {
        let node = s.add_node(&format!("prop {k}"), None, Trs::default());
        let on_table = k % 3 == 0;
        let (row, y) = if on_table {
            ((k / 3) % 3, 0.76 + 0.2)
        } else {
            (k % 3, 0.2)
        };
        let z = if on_table {
            [2.2, 9.0, 15.8][row] + (unit(k, 1) - 0.5) * 0.6
        } else {
            [6.5, 11.0, 1.0 + 16.0 * unit(k, 1)][row]
        };
        let x0 = 1.0 + unit(k, 2) * (LENGTH - 6.0);
        let reach = 1.0 + unit(k, 3) * 3.0;
        let period = 4.0 + unit(k, 4) * 8.0;
        let a = Vec3::new(x0, y, z);
        let b = Vec3::new(x0 + reach, y, z);
        match mesh {
            None => {
                let i = s.add_on_node(Mesh::cuboid(Vec3::splat(-0.2), Vec3::splat(0.2)), node);
                mesh = Some(s.instances[i].mesh);
            }
            Some(m) => s.instances.push(Instance {
                mesh: m,
                transform: Affine3A::IDENTITY,
                node: Some(node),
                skin: None,
            }),
        }
        s.animations.push(Animation::translation(
            &format!("prop {k}"),
            node,
            &[(0.0, a), (period / 2.0, b), (period, a)],
        ));
    }
}

/// `n` CesiumMan figures walking the aisles from end to end and back, in
/// four lanes, every other pair the other way.
fn add_figures(s: &mut Scene, n: usize) {
    if n == 0 {
        return;
    }
    let man = load_gltf_slice(super::default_scene::CESIUM_MAN, "CesiumMan.glb", None)
        .expect("the embedded CesiumMan model loads");
    for k in 0..n {
        let root = s.add_node(&format!("figure {k}"), None, Trs::default());
        s.append(man.clone(), Some(root));
        let z = [6.8, 11.2, 7.6, 10.4][k % 4];
        // Every other pair walks the other way.
        let (x0, x1) = if (k / 2) % 2 == 0 {
            (3.0, LENGTH - 3.0)
        } else {
            (LENGTH - 3.0, 3.0)
        };
        let turned = if x1 > x0 { 0.0 } else { std::f32::consts::PI };
        let walk = 24.0;
        let turn = 1.0;
        let times = vec![
            0.0,
            walk,
            walk + turn,
            2.0 * walk + turn,
            2.0 * walk + 2.0 * turn,
        ];
        let at = |x: f32| Vec3::new(x, 0.0, z);
        // Modelled facing +z: a quarter turn faces +x.
        let yaw = |a: f32| Quat::from_rotation_y(std::f32::consts::FRAC_PI_2 + a);
        let pi = std::f32::consts::PI;
        s.animations.push(Animation {
            name: format!("figure {k} path"),
            channels: vec![
                Channel {
                    node: root,
                    times: times.clone(),
                    keys: Keys::Translation(vec![at(x0), at(x1), at(x1), at(x0), at(x0)]),
                    interpolation: Interpolation::Linear,
                },
                Channel {
                    node: root,
                    times,
                    keys: Keys::Rotation(
                        [0.0, 0.0, pi, pi, 2.0 * pi]
                            .map(|a| yaw(turned + a))
                            .to_vec(),
                    ),
                    interpolation: Interpolation::Linear,
                },
            ],
        });
    }
}

/// 30 s down the hall and back at eye height, looking ahead and across.
fn camera_path() -> CameraPath {
    let key = |time: f32, eye: Vec3, target: Vec3| CameraKey { time, eye, target };
    CameraPath {
        keys: vec![
            key(0.0, Vec3::new(1.5, 1.7, 9.0), Vec3::new(18.0, 1.0, 9.0)),
            key(10.0, Vec3::new(18.0, 2.2, 7.0), Vec3::new(30.0, 0.8, 12.0)),
            key(20.0, Vec3::new(34.0, 1.7, 11.0), Vec3::new(18.0, 1.0, 6.0)),
            key(30.0, Vec3::new(1.5, 1.7, 9.0), Vec3::new(18.0, 1.0, 9.0)),
        ],
        fov_y: 60f32.to_radians(),
    }
}

/// The hall's table, standing on y = 0 around the origin: a 4 cm top
/// (1.6 m by 0.9 m, its top at y = 0.76) on a block whose top face
/// (y = 0.72) lies on the top's underside, hidden: the case buried
/// points are for.
pub fn hall_table() -> Mesh {
    let mut table = Mesh::cuboid(Vec3::new(-0.8, 0.72, -0.45), Vec3::new(0.8, 0.76, 0.45));
    let leg = Mesh::cuboid(Vec3::new(-0.6, 0.0, -0.3), Vec3::new(0.6, 0.72, 0.3));
    let base = table.positions.len() as u32;
    table.positions.extend(leg.positions);
    table.normals.extend(leg.normals);
    table.indices.extend(leg.indices.iter().map(|i| base + i));
    table
}
