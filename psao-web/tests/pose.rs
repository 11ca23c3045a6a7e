//! The page poses deforming instances where psao-scene does: the default
//! scene's walker (a skin) and a cube whose morph weights an animation
//! drives, exported by `psao_scene::export::glb`, posed by the page's own
//! glb.js and pose.js on Node, against `Scene::deform_into` at a sample
//! time (equal to float rounding) and between two samples (the sampling's
//! interpolation error, bounded).
//!
//! Needs Node; without it the test says it skips, unless
//! `PSAO_REQUIRE_BROWSER` is set.

use std::path::Path;
use std::process::Command;

use glam::Vec3;
use psao_scene::export::glb::{SKIN_SAMPLES_PER_SECOND, to_glb};
use psao_scene::{WALKER, default_scene};

fn posed_by_the_page(glb: &Path, instance: usize, t: f32) -> Option<(Vec<f32>, Vec<f32>)> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/node/pose.mjs");
    let out = match Command::new("node")
        .arg(script)
        .arg(glb)
        .arg(instance.to_string())
        .arg(t.to_string())
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            assert!(
                std::env::var_os("PSAO_REQUIRE_BROWSER").is_none(),
                "PSAO_REQUIRE_BROWSER is set and node cannot run: {e}"
            );
            eprintln!("skipped: no node ({e})");
            return None;
        }
    };
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let floats = |k: &str| -> Vec<f32> {
        v[k].as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect()
    };
    Some((floats("positions"), floats("normals")))
}

/// The largest distance between the page's posed vertices and the scene's.
fn worst(page: &[f32], scene: &[Vec3]) -> f32 {
    assert_eq!(page.len(), 3 * scene.len());
    scene
        .iter()
        .enumerate()
        .map(|(v, p)| (Vec3::from_slice(&page[3 * v..3 * v + 3]) - *p).length())
        .fold(0.0, f32::max)
}

/// Exports `scene`, poses `instance` with the page's code at a sample time
/// and between two, and compares with the scene's own deformation.
fn compare(scene: &psao_scene::Scene, instance: usize, name: &str) {
    let glb = to_glb(scene, |i| scene.deforms(i)).unwrap();
    let file = std::env::temp_dir().join(format!("psao-pose-{name}-{}.glb", std::process::id()));
    std::fs::write(&file, &glb).unwrap();
    let (mut p, mut n) = (Vec::new(), Vec::new());
    let size = scene.meshes[scene.instances[instance].mesh]
        .bounds()
        .map_or(1.0, |(lo, hi)| (hi - lo).length());
    // A sample's time, and halfway between two samples.
    for (k, (t, bound)) in [
        (37.0 / SKIN_SAMPLES_PER_SECOND, 1e-4),
        (37.5 / SKIN_SAMPLES_PER_SECOND, 0.01),
    ]
    .into_iter()
    .enumerate()
    {
        let Some((page_p, page_n)) = posed_by_the_page(&file, instance, t) else {
            return;
        };
        scene.deform_into(instance, &scene.pose(t), &mut p, &mut n);
        let d = worst(&page_p, &p);
        eprintln!(
            "{name}, t = {t:.4} s: worst distance {d:.2e} ({:.2e} of its size)",
            d / size
        );
        assert!(
            d <= bound * size,
            "{name}, case {k}: {d} against {}",
            bound * size
        );
        let normals = worst(&page_n, &n);
        assert!(
            normals <= if k == 0 { 1e-3 } else { 0.1 },
            "{name}, case {k}: normals {normals}"
        );
        // The pose is not the rest shape (or the comparison says nothing).
        let rest = &scene.meshes[scene.instances[instance].mesh].positions;
        let moved = worst(&page_p, rest);
        assert!(moved > 0.01 * size, "{name}, case {k}: {moved} from rest");
    }
    let _ = std::fs::remove_file(&file);
}

#[test]
fn the_page_poses_the_walker_where_the_scene_does() {
    compare(&default_scene(), WALKER, "walker");
}

#[test]
fn the_page_morphs_the_cube_where_the_scene_does() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../psao-scene/tests/data/AnimatedMorphCube.glb");
    let scene = psao_scene::stage(psao_scene::load_gltf(&file).unwrap()).unwrap();
    let cube = (0..scene.instances.len())
        .find(|&i| scene.meshes[scene.instances[i].mesh].morph.is_some())
        .expect("a morphing instance");
    compare(&scene, cube, "morph cube");
}
