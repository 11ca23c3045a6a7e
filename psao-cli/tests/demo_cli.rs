//! `psao demo` end to end, briefly: its images follow `--camera` or
//! `--camera-path` instead of the scene's camera path.

use std::path::PathBuf;
use std::process::Command;

fn demo(name: &str, extra: &[&str]) -> (PathBuf, String) {
    let out = std::env::temp_dir().join(format!("psao-demo-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let run = Command::new(env!("CARGO_BIN_EXE_psao"))
        .args([
            "demo",
            "--seconds",
            "0.3",
            "--images",
            "1",
            "--density",
            "8",
        ])
        .args(extra)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&run.stdout).into_owned() + &String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{extra:?}: {text}");
    (out, text)
}

#[test]
fn demo_images_follow_the_camera_it_is_given() {
    let image = |out: &PathBuf| {
        image::open(out.join("demo-01-lit.png"))
            .unwrap()
            .to_luma32f()
            .into_raw()
    };
    // Mean absolute difference of two pictures.
    let diff = |a: &[f32], b: &[f32]| {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.len() as f32
    };
    let (scene_path, _) = demo("own", &[]);
    let (fixed, text) = demo("fixed", &["--camera=4,9,6.1,4,0,6", "--fov", "70"]);
    assert!(text.contains("mirrors             1 of 1 equal"), "{text}");
    let moved = diff(&image(&scene_path), &image(&fixed));
    // The same camera from a path file gives the same picture (up to the
    // AO of the frame the client holds at the shot).
    let file = std::env::temp_dir().join(format!("psao-demo-path-{}.txt", std::process::id()));
    std::fs::write(&file, "fov 70\n0  4 9 6.1  4 0 6\n").unwrap();
    let (from_file, _) = demo("file", &["--camera-path", file.to_str().unwrap()]);
    let same = diff(&image(&fixed), &image(&from_file));
    assert!(moved > 0.05 && same < moved / 10.0, "{moved} {same}");
    for out in [scene_path, fixed, from_file] {
        let _ = std::fs::remove_dir_all(out);
    }
    let _ = std::fs::remove_file(file);
}
