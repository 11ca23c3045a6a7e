//! Staging: objects get a floor and an orbit, interiors a camera inside,
//! and either camera fills at least half the picture.

use glam::{Affine3A, Vec3};
use psao_eval::path_coverage;
use psao_scene::*;

/// An 8 x 3 x 6 m room whose faces point inward, with a table in it.
fn room() -> Scene {
    let mut walls = Mesh::cuboid(Vec3::new(-4.0, 0.0, -3.0), Vec3::new(4.0, 3.0, 3.0));
    for t in walls.indices.chunks_exact_mut(3) {
        t.swap(1, 2);
    }
    for n in &mut walls.normals {
        *n = -*n;
    }
    let mut s = Scene::default();
    s.add(walls.subdivided(2), Affine3A::IDENTITY);
    s.add(
        Mesh::cuboid(Vec3::new(-0.8, 0.0, -0.5), Vec3::new(0.8, 0.8, 0.5)),
        Affine3A::IDENTITY,
    );
    s
}

fn key_times(s: &Scene) -> Vec<f32> {
    let d = s.camera.as_ref().unwrap().duration();
    (0..8).map(|k| d * k as f32 / 8.0).collect()
}

#[test]
fn an_inward_room_is_staged_as_an_interior_seen_from_inside() {
    let r = room();
    assert_eq!(setting(&r).unwrap(), Some(Setting::Interior));
    let staged = stage(r.clone()).unwrap();
    assert_eq!(staged.instances.len(), 2, "no floor added to a room");
    let cov = path_coverage(&staged, &key_times(&staged), 64, 36).unwrap();
    assert!(cov.iter().all(|&c| c >= 0.99), "{cov:?}");
    // Negative control: the object orbit sees the room from outside,
    // where its walls are back faces and culled.
    let mut outside = r;
    outside.camera =
        Some(CameraPath::fixed(Vec3::new(9.0, 5.0, 9.0), Vec3::new(0.0, 1.0, 0.0), 0.9).unwrap());
    let seen = path_coverage(&outside, &[0.0], 64, 36).unwrap()[0];
    assert!(seen < 0.5, "{seen}");
}

#[test]
fn an_object_gets_a_floor_sized_to_it_and_an_orbit_that_sees_it() {
    // A 7 cm box: the floor margin is capped by its size, not 2 m.
    let mut s = Scene::default();
    s.add(
        Mesh::cuboid(Vec3::ZERO, Vec3::splat(0.07)),
        Affine3A::IDENTITY,
    );
    assert_eq!(setting(&s).unwrap(), Some(Setting::Object));
    let staged = stage(s).unwrap();
    assert_eq!(staged.instances.len(), 2);
    let floor = staged.meshes[staged.instances[1].mesh].bounds().unwrap();
    let width = floor.1.x - floor.0.x;
    assert!(
        (width - 0.07 * (1.0 + 2.0 * FLOOR_MARGIN_EXTENTS)).abs() < 1e-4,
        "{width}"
    );
    let cov = path_coverage(&staged, &key_times(&staged), 64, 36).unwrap();
    assert!(cov.iter().all(|&c| c >= 0.5), "{cov:?}");
}

#[test]
fn the_cornell_box_is_an_interior_and_its_camera_fills_the_picture() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../psao-scene/tests/data/CornellBox.glb");
    let s = load_gltf(&path).unwrap();
    let share = {
        let tris = s.world_triangles().unwrap();
        let (lo, hi) = tris
            .iter()
            .flatten()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), p| {
                (a.min(*p), b.max(*p))
            });
        front_share(tris, (lo + hi) * 0.5)
    };
    assert!(share >= INTERIOR_SHARE, "{share}");
    assert_eq!(setting(&s).unwrap(), Some(Setting::Interior));
    let staged = stage(s.clone()).unwrap();
    assert_eq!(staged.instances.len(), s.instances.len(), "no floor");
    let cov = path_coverage(&staged, &key_times(&staged), 64, 36).unwrap();
    assert!(cov.iter().all(|&c| c >= 0.5), "{cov:?}");
}

/// The Cameras sample frames its 1 m square from 3 m away: its own camera
/// covers well under half the picture, as its author chose. Without it
/// (`psao bench --auto-camera`) the automatic camera fills at least half.
#[test]
fn a_file_camera_is_kept_as_authored_and_the_automatic_one_fills_half() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../psao-scene/tests/data/Cameras.gltf");
    let s = load_gltf(&path).unwrap();
    assert!(s.camera.is_some(), "the file's camera is imported");
    let own = stage(s.clone()).unwrap();
    let cov = path_coverage(&own, &[0.0], 64, 36).unwrap()[0];
    assert!(cov > 0.05 && cov < 0.5, "{cov}");
    let mut auto = s;
    auto.camera = None;
    let auto = stage(auto).unwrap();
    let cov = path_coverage(&auto, &key_times(&auto), 64, 36).unwrap();
    assert!(cov.iter().all(|&c| c >= 0.5), "{cov:?}");
}

#[test]
fn camera_paths_read_from_text_and_fixed_cameras_are_checked() {
    let text = "# a path\nfov 40\n0 1,2,3 0 0 0\n2.5\t4 5 6  0 1 0 # look up\n\n";
    let p = CameraPath::parse(text).unwrap();
    assert_eq!(p.keys.len(), 2);
    assert!((p.fov_y - 40f32.to_radians()).abs() < 1e-6);
    assert_eq!(p.keys[1].eye, Vec3::new(4.0, 5.0, 6.0));
    assert_eq!(p.keys[1].target, Vec3::Y);
    // The text form reads back.
    let back = CameraPath::parse(&p.to_text()).unwrap();
    assert_eq!(back.keys, p.keys);
    assert!((back.fov_y - p.fov_y).abs() < 1e-6);
    // Errors name the line and what was wrong.
    for (bad, why) in [
        ("0 1 2 3 0 0\n", "line 1: 6 numbers"),
        ("0 1 2 3 0 0 x\n", "line 1: `x` is not a finite number"),
        ("0 1 2 3 0 0 inf\n", "not a finite number"),
        ("fov 200\n0 1 2 3 0 0 0\n", "line 1: fov 200"),
        ("fov 40\nfov 50\n", "line 2: a second fov"),
        ("1 0 0 1 0 0 0\n0 0 0 2 0 0 0\n", "increase strictly"),
        ("0 1 1 1 1 1 1\n", "own eye"),
        ("# nothing\n", "no keys"),
        (", ,\n,\n", "no keys"),
    ] {
        let e = CameraPath::parse(bad).unwrap_err().to_string();
        assert!(e.contains(why), "{bad:?}: {e}");
    }
    assert!(CameraPath::fixed(Vec3::ONE, Vec3::ONE, 0.9).is_err());
    assert!(CameraPath::fixed(Vec3::ONE, Vec3::ZERO, 4.0).is_err());
    // A file names itself in errors, and too large a file is refused.
    let dir = std::env::temp_dir().join(format!("psao-camera-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let f = dir.join("path.txt");
    std::fs::write(&f, "0 1 2 3 0 0\n").unwrap();
    let e = CameraPath::load(&f).unwrap_err().to_string();
    assert!(e.contains("path.txt") && e.contains("line 1"), "{e}");
    std::fs::write(&f, vec![b'#'; MAX_CAMERA_PATH_BYTES as usize + 1]).unwrap();
    let e = CameraPath::load(&f).unwrap_err().to_string();
    assert!(e.contains("larger than"), "{e}");
    let e = CameraPath::load(&dir.join("missing.txt"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.txt"), "{e}");
    // A folder (as a pipe or a device) is not a regular file.
    let e = CameraPath::load(&dir).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_panel_facing_one_way_is_seen_from_its_front() {
    // A 4 x 3 m single-sided panel facing +Z: from behind it is culled.
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-2.0, 0.0, 0.0), Vec3::X * 4.0, Vec3::Y * 3.0),
        Affine3A::IDENTITY,
    );
    let staged = stage(s).unwrap();
    let path = staged.camera.clone().unwrap();
    assert!(path.keys.iter().all(|k| k.eye.z > 0.5), "{:?}", path.keys);
    let cov = path_coverage(&staged, &key_times(&staged), 64, 36).unwrap();
    assert!(cov.iter().all(|&c| c >= 0.5), "{cov:?}");
    // Mirrored by a node (det < 0), the panel faces -Z: seen from there.
    let mut m = Scene::default();
    m.add(
        Mesh::quad(Vec3::new(-2.0, 0.0, 0.0), Vec3::X * 4.0, Vec3::Y * 3.0),
        Affine3A::from_scale(Vec3::new(1.0, 1.0, -1.0)),
    );
    let path = stage(m).unwrap().camera.unwrap();
    assert!(path.keys.iter().all(|k| k.eye.z < -0.5), "{:?}", path.keys);
}
