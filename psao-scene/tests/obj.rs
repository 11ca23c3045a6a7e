//! Wavefront OBJ import: geometry, normals made from faces, materials'
//! dissolve as alpha, hostile input, and the choice by extension.

use std::path::PathBuf;

use glam::Vec3;
use psao_scene::*;

/// A unit cube of 8 shared vertices and 6 quads, without normals, in two
/// groups; the top quad uses the material `glass`.
const CUBE: &str = "\
mtllib cube.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
g sides
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 4 1 5 8
g top
usemtl glass
f 3 4 8 7
";

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("psao-obj-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn an_obj_file_loads_with_face_normals_and_its_materials_dissolve() {
    let dir = temp_dir("cube");
    std::fs::write(dir.join("cube.obj"), CUBE).unwrap();
    std::fs::write(dir.join("cube.mtl"), "newmtl glass\nd 0.25\n").unwrap();
    let s = load_scene_file(&dir.join("cube.obj")).unwrap();
    assert_eq!(s.instances.len(), 2, "one instance per group");
    let sides = &s.meshes[s.instances[0].mesh];
    let top = &s.meshes[s.instances[1].mesh];
    assert_eq!((sides.triangle_count(), top.triangle_count()), (10, 2));
    // Normals from the faces: the top faces +y.
    assert!(
        top.normals.iter().all(|n| (*n - Vec3::Y).length() < 1e-5),
        "{:?}",
        top.normals
    );
    // The glass is see-through (dissolve 0.25 below the 0.5 cut-out).
    let mask = top.alpha.as_ref().expect("the dissolve became a mask");
    assert_eq!(mask.factor, 0.25);
    assert!(!top.solid(0, [1.0 / 3.0; 3]));
    assert!(sides.alpha.is_none());
    // It streams like any scene.
    let p = Pipeline::new(s, PipelineConfig::with_density_and_rays(400.0, 8)).unwrap();
    assert!(p.points(0).unwrap().len() > 500);
    // Without its material library, every face is solid.
    let s = load_obj_slice(CUBE.as_bytes(), "cube.obj", None).unwrap();
    assert!(s.meshes.iter().all(|m| m.alpha.is_none()));
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn the_normals_a_file_gives_are_kept() {
    let quad = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nvn 0 2 0\nf 1//1 4//1 3//1 2//1\n";
    let s = load_obj_slice(quad.as_bytes(), "quad.obj", None).unwrap();
    let m = &s.meshes[0];
    assert_eq!(m.triangle_count(), 2);
    assert!(
        m.normals.iter().all(|n| *n == Vec3::Y),
        "unit length, as given"
    );
}

#[test]
fn bad_obj_input_is_a_typed_error_naming_the_file() {
    for (text, what) in [
        ("v 0 0 0\nv 1 0 0\nf 1 2 9\n", "index out of bounds"),
        ("v 0 0 x\nf 1 1 1\n", "parse error"),
        ("", "no faces"),
        (
            "v 0 0 0\nv 1 0 0\nv nan 0 0\nf 1 2 3\n",
            "vertex 2 is not finite",
        ),
    ] {
        let e = load_obj_slice(text.as_bytes(), "bad.obj", None).unwrap_err();
        let s = e.to_string();
        assert!(matches!(e, SceneError::Obj { .. }), "{s}");
        assert!(s.starts_with("OBJ bad.obj: ") && s.contains(what), "{s}");
    }
    let e = load_scene_file(std::path::Path::new("/nonexistent/room.obj")).unwrap_err();
    assert!(
        matches!(e, SceneError::Obj { ref element, .. } if element == "file"),
        "{e}"
    );
}

#[test]
fn other_files_say_which_formats_are_read() {
    for name in ["bunny.ply", "scene.fbx", "noextension"] {
        let e = load_scene_file(std::path::Path::new(name)).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!("unsupported scene format: expected .gltf, .glb or .obj ({name})")
        );
    }
    // The extension is read without regard to case.
    let e = load_scene_file(std::path::Path::new("/nonexistent/ROOM.GLB")).unwrap_err();
    assert!(matches!(e, SceneError::Gltf { .. }), "{e}");
}

#[test]
fn material_libraries_outside_the_folder_or_not_files_are_left_out() {
    let dir = temp_dir("escape");
    std::fs::create_dir_all(dir.join("inner")).unwrap();
    // A library one folder up, and one named by an absolute path: neither
    // is read, so the faces stay solid.
    std::fs::write(dir.join("up.mtl"), "newmtl glass\nd 0.25\n").unwrap();
    for lib in ["../up.mtl", "/dev/zero"] {
        let obj = CUBE.replace("mtllib cube.mtl", &format!("mtllib {lib}"));
        std::fs::write(dir.join("inner/cube.obj"), obj).unwrap();
        let s = load_scene_file(&dir.join("inner/cube.obj")).unwrap();
        assert!(s.meshes.iter().all(|m| m.alpha.is_none()), "{lib} was read");
    }
    std::fs::remove_dir_all(dir).ok();
}
