//! Small scenes for tests: a floor and a box sliding over it, so that
//! something changes every frame, a plate leaning on a floor, the pipeline
//! settings tests use, and the points of a pipeline in world space.

use glam::{Affine3A, Vec3};
use psao_scene::{Animation, Mesh, Pipeline, PipelineConfig, Scene, Trs};

/// A 6 m floor (subdivided twice) and a 0.6 m box sliding over it from
/// x = -2 to 2 and back over 4 s.
pub fn sliding_box() -> Scene {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-3.0, 0.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0).subdivided(2),
        Affine3A::IDENTITY,
    );
    let node = s.add_node("box", None, Trs::default());
    s.add_on_node(Mesh::cuboid(Vec3::splat(-0.3), Vec3::splat(0.3)), node);
    s.animations.push(Animation::translation(
        "slide",
        node,
        &[
            (0.0, Vec3::new(-2.0, 0.3, 0.0)),
            (2.0, Vec3::new(2.0, 0.3, 0.0)),
            (4.0, Vec3::new(-2.0, 0.3, 0.0)),
        ],
    ));
    s
}

/// A 4 m floor, and a 1.2 m x 1.2 m plate 4 mm thick leaning at 40 degrees
/// over x > 0, its lower edge on the floor along the z axis (issue 15's
/// leaning plate: the floor points in the acute wedge under it are dark).
pub fn leaning_plate() -> Scene {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::Z * 4.0, Vec3::X * 4.0).subdivided(2),
        Affine3A::IDENTITY,
    );
    s.add(
        Mesh::cuboid(Vec3::new(0.0, 0.0, -0.6), Vec3::new(1.2, 0.004, 0.6)),
        Affine3A::from_rotation_translation(
            glam::Quat::from_rotation_z(40f32.to_radians()),
            Vec3::ZERO,
        ),
    );
    s
}

/// A camera on [`leaning_plate`]'s open side, above: it sees the plate's
/// upper face and the floor in front of its foot, not the wedge under it.
pub fn leaning_plate_camera() -> psao_scene::Camera {
    psao_scene::Camera {
        eye: Vec3::new(-2.2, 1.6, 0.4),
        target: Vec3::new(0.1, 0.1, 0.0),
        fov_y: 0.8,
    }
}

/// A pipeline at `density` points per square metre with `rays` AO rays per
/// point, the rest default.
pub fn pipeline_config(density: f32, rays: u32) -> PipelineConfig {
    PipelineConfig::with_density_and_rays(density, rays)
}

/// A pipeline over `scene` with [`pipeline_config`]`(density, rays)`.
///
/// # Panics
/// If the scene does not build (tests pass scenes that do).
pub fn pipeline(scene: &Scene, density: f32, rays: u32) -> Pipeline {
    Pipeline::new(scene.clone(), pipeline_config(density, rays)).expect("the scene builds")
}

/// Every point of the pipeline's instances in world space (ids numbered
/// across instances, positions, unit normals), to trace with another
/// backend.
pub fn world_points(p: &Pipeline) -> (Vec<u32>, Vec<Vec3>, Vec<Vec3>) {
    let (mut ids, mut pts, mut nrm) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..p.instance_count() {
        let (Some((pos, n)), Some(t)) = (p.current_points(i), p.transform(i)) else {
            continue;
        };
        let nm = psao_scene::normal_matrix(&t);
        for k in 0..pos.len() {
            ids.push(ids.len() as u32);
            pts.push(t.transform_point3(pos[k]));
            nrm.push((nm * n[k]).normalize());
        }
    }
    (ids, pts, nrm)
}
