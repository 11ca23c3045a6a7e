//! The page poses a skinned instance where psao-scene does: the default
//! scene's walker, exported by `psao_scene::export::glb`, posed by the
//! page's own glb.js and skin.js on Node, against `Scene::deform_into` at
//! a sample time (equal to float rounding) and between two samples (the
//! sampling's interpolation error, bounded).
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

#[test]
fn the_page_poses_the_walker_where_the_scene_does() {
    let scene = default_scene();
    let glb = to_glb(&scene, |i| scene.deforms(i)).unwrap();
    let file = std::env::temp_dir().join(format!("psao-skin-{}.glb", std::process::id()));
    std::fs::write(&file, &glb).unwrap();
    let (mut p, mut n) = (Vec::new(), Vec::new());
    let size = scene.meshes[scene.instances[WALKER].mesh]
        .bounds()
        .map_or(1.0, |(lo, hi)| (hi - lo).length());
    // A sample's time, and halfway between two samples.
    for (k, (t, bound)) in [
        (7.0 / SKIN_SAMPLES_PER_SECOND, 1e-4),
        (7.5 / SKIN_SAMPLES_PER_SECOND, 0.01),
    ]
    .into_iter()
    .enumerate()
    {
        let Some((page_p, page_n)) = posed_by_the_page(&file, WALKER, t) else {
            return;
        };
        scene.deform_into(WALKER, &scene.pose(t), &mut p, &mut n);
        let d = worst(&page_p, &p);
        eprintln!(
            "t = {t:.4} s: worst distance {d:.2e} ({:.2e} of the figure's size)",
            d / size
        );
        assert!(d <= bound * size, "case {k}: {d} against {}", bound * size);
        let normals = worst(&page_n, &n);
        assert!(
            normals <= if k == 0 { 1e-3 } else { 0.1 },
            "case {k}: normals {normals}"
        );
    }
    let _ = std::fs::remove_file(&file);
}
