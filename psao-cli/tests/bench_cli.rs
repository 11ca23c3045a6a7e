//! `psao bench` end to end at a tiny size: it writes the CSV, the markdown
//! table, the charts and the images (of the frames `--image-frames` names),
//! with one row per configuration, and refuses bad settings with a message.

use std::path::PathBuf;
use std::process::Command;

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("psao-bench-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn bench_writes_its_table_charts_and_images() {
    let out = out_dir("tiny");
    let run = Command::new(env!("CARGO_BIN_EXE_psao"))
        .args([
            "bench",
            "--width",
            "40",
            "--height",
            "24",
            "--frames",
            "2",
            "--reference-rays",
            "16",
            "--point-rays",
            "8",
            "--densities",
            "8,32",
            "--rates",
            "60,5",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "psao bench failed: {stderr}");
    let csv = std::fs::read_to_string(out.join("bench.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    let header: Vec<&str> = lines[0].split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    // Per scene: PSAO at 2 densities at 60 Hz, the focus density at 5 Hz,
    // RTAO at 1, 4 and 16 rays, SAO.
    let per_scene = 2 + 1 + 3 + 1;
    assert_eq!(lines.len(), 1 + 2 * per_scene, "{csv}");
    for scene in ["default", "cesium-man"] {
        let rows: Vec<Vec<&str>> = lines[1..]
            .iter()
            .map(|l| l.split(',').collect::<Vec<_>>())
            .filter(|r| r[0] == scene)
            .collect();
        assert_eq!(rows.len(), per_scene, "{scene}");
        for r in &rows {
            let psnr: f64 = r[col("psnr_db")].parse().unwrap();
            let rmse: f64 = r[col("rmse")].parse().unwrap();
            let ssim: f64 = r[col("ssim")].parse().unwrap();
            let flip: f64 = r[col("flip")].parse().unwrap();
            let client: f64 = r[col("client_ms")].parse().unwrap();
            assert!(psnr > 0.0 && rmse > 0.0 && rmse < 1.0, "{r:?}");
            assert!((0.0..=1.0).contains(&ssim) && (0.0..=1.0).contains(&flip));
            assert!(client > 0.0);
            if r[col("method")] == "psao" {
                let mbit: f64 = r[col("mbit_s")].parse().unwrap();
                let points: usize = r[col("points")].parse().unwrap();
                assert!(mbit >= 0.0 && points > 0, "{r:?}");
            } else {
                assert_eq!(r[col("mbit_s")], "", "only PSAO streams");
            }
        }
        // Denser points, more of them on the server.
        let points = |d: &str| -> usize {
            rows.iter()
                .find(|r| r[col("density")] == d && r[col("rate_hz")] == "60")
                .unwrap()[col("points")]
            .parse()
            .unwrap()
        };
        assert!(points("32") > points("8"));
        for file in ["frame", "time-error", "bitrate-error", "ao-reference"] {
            let path = out.join(format!("{scene}-{file}.png"));
            let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(img.width() >= 40 && img.height() >= 24);
        }
        for file in [
            "ao-reference",
            "gbuffer-position",
            "gbuffer-normal",
            "gbuffer-depth-instance",
        ] {
            let path = out.join(format!("{scene}-{file}.exr"));
            let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!((img.width(), img.height()), (40, 24));
        }
    }
    // The reference AO file holds the values, 16 bits deep.
    let ao = image::open(out.join("default-ao-reference.png")).unwrap();
    assert!(matches!(ao.color(), image::ColorType::L16));
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(md.contains("| PSAO-32 @60 Hz |"), "{md}");
    assert!(md.contains("| SAO |") && md.contains("| RTAO-16spp |"));
    assert!(md.contains("against SAO:") && md.contains("target +3 dB"));
    // Setup and keyframe size in the table, for every PSAO row.
    assert!(md.contains("| setup s | keyframe kB |"), "{md}");
    assert!(md.contains("(radius 0.6)"), "{md}");
    // The backend, as .ci/run looks for it in the GPU bench's report.
    assert!(md.contains("traced on the CPU backend ("), "{md}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_ray_budget_adds_budgeted_rows_beside_the_others() {
    let out = out_dir("budget");
    let run = Command::new(env!("CARGO_BIN_EXE_psao"))
        .args([
            "bench",
            "--scenes",
            "cesium-man",
            "--width",
            "32",
            "--height",
            "20",
            "--frames",
            "2",
            "--reference-rays",
            "8",
            "--point-rays",
            "8",
            "--densities",
            "16",
            "--rates",
            "60",
            "--ray-budget",
            "64",
            "--max-wait",
            "3",
            "--max-wait-limit",
            "5",
            "--image-frames",
            "0",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "psao bench failed: {stderr}");
    let csv = std::fs::read_to_string(out.join("bench.csv")).unwrap();
    let methods: Vec<&str> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap())
        .collect();
    assert_eq!(methods.iter().filter(|m| **m == "psao").count(), 1, "{csv}");
    assert_eq!(
        methods.iter().filter(|m| **m == "psao-budget").count(),
        1,
        "{csv}"
    );
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap();
    assert!(md.contains("| PSAO-16 @60 Hz budget |"), "{md}");
    // The verdict compares it with the unbudgeted server and states the
    // longest wait, which the bound on waiting keeps within
    // --max-wait-limit (a 64-ray budget is far below the demand, so the
    // bound may rise from --max-wait to it).
    let verdict = md
        .lines()
        .find(|l| l.starts_with("- PSAO-16 @60 Hz budget: server"))
        .unwrap_or_else(|| panic!("{md}"));
    let waited: u32 = verdict
        .rsplit("no point waited more than ")
        .next()
        .and_then(|t| t.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{verdict}"));
    assert!(waited <= 5, "{verdict}");
    // It states the rays each server cast a tick: the budgeted one, far
    // below its demand, casts fewer.
    let rays: Vec<f64> = verdict
        .split(" rays a tick")
        .next()
        .and_then(|t| t.rsplit(", ").next())
        .map(|t| {
            t.split(" against ")
                .filter_map(|n| n.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    assert!(
        rays.len() == 2 && rays[0] > 0.0 && rays[0] < rays[1],
        "{verdict}"
    );
    // And how many of the ticks it timed ran past the period (at most
    // all of them; the window is a second at 60 Hz), and the longest.
    let ticks: Vec<f64> = verdict
        .split(" ticks over the period (longest ")
        .next()
        .and_then(|t| t.rsplit("; ").next())
        .map(|t| t.split(" of ").filter_map(|n| n.parse().ok()).collect())
        .unwrap_or_default();
    assert!(
        ticks.len() == 2 && ticks[0] <= ticks[1] && ticks[1] == 60.0,
        "{verdict}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn bench_refuses_bad_settings() {
    for (args, says) in [
        (vec!["--frames", "0"], "--frames"),
        (vec!["--rates", "60,0"], "0 Hz"),
        (vec!["--densities=-5,16"], "density -5"),
        (vec!["--only-gltf"], "--gltf"),
        (vec!["--gltf", "/nonexistent/scene.glb"], "scene.glb"),
        (
            vec!["--gltf", "/nonexistent/bunny.ply"],
            "unsupported scene format",
        ),
        (vec!["--radius", "0"], "--radius 0"),
        (
            vec!["--ray-budget", "lots"],
            "expected auto, auto:SHARE, none or a number",
        ),
        (
            vec!["--ray-budget", "auto:2"],
            "a share of the frame period",
        ),
        (
            vec!["--frames", "2", "--image-frames", "0,2"],
            "--image-frames 2 is out of range",
        ),
        (vec!["--image-frames", "1,x"], "`x` is not a frame index"),
        (vec!["--image-frames=-1"], "`-1` is not a frame index"),
        (vec!["--scenes", "default,bogus"], "invalid value 'bogus'"),
        (vec!["--camera", "1,2,3"], "3 numbers; expected six"),
        (
            vec!["--camera", "1,2,3,4,5,x"],
            "`x` is not a finite number",
        ),
        (vec!["--camera", "1,1,1,1,1,1"], "own eye"),
        (vec!["--fov", "40"], "--camera"),
        (vec!["--camera-path", "/nonexistent/path.txt"], "path.txt"),
        (
            vec!["--camera", "0,0,1,0,0,0", "--camera-path", "p.txt"],
            "cannot be used with",
        ),
    ] {
        let out = out_dir("bad");
        let run = Command::new(env!("CARGO_BIN_EXE_psao"))
            .arg("bench")
            .args(&args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{args:?} was accepted");
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        let _ = std::fs::remove_dir_all(&out);
    }
}

#[test]
fn bench_writes_the_images_of_the_frames_asked_for() {
    let out = out_dir("image-frames");
    let run = Command::new(env!("CARGO_BIN_EXE_psao"))
        .args([
            "bench",
            "--width",
            "64",
            "--height",
            "36",
            "--frames",
            "2",
            "--reference-rays",
            "8",
            "--point-rays",
            "8",
            "--densities",
            "16",
            "--rates",
            "30",
            "--image-frames",
            "1",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "psao bench failed: {stderr}");
    for scene in ["default", "cesium-man"] {
        // Frame 1's files carry its index after the scene's name.
        for file in [
            "frame.png",
            "ao-reference.png",
            "ao-psao-16-30-hz.png",
            "ao-rtao-1spp.png",
            "ao-sao.png",
            "ao-reference.exr",
            "gbuffer-position.exr",
            "gbuffer-normal.exr",
            "gbuffer-depth-instance.exr",
        ] {
            let path = out.join(format!("{scene}-f1-{file}"));
            let img = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(
                img.width() >= 64 && img.height() >= 36,
                "{}",
                path.display()
            );
        }
        // Frame 0 was not asked for: none of its files.
        for file in ["frame.png", "ao-reference.png", "ao-reference.exr"] {
            let path = out.join(format!("{scene}-{file}"));
            assert!(!path.exists(), "{} written", path.display());
        }
        // The charts do not depend on the frames saved.
        assert!(out.join(format!("{scene}-time-error.png")).exists());
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// A tiny bench of the Cornell box (555 units, a room facing inward) with
/// the given extra arguments; returns (success, stdout + stderr, bench.md).
fn cornell(name: &str, extra: &[&str]) -> (bool, String, String) {
    let out = out_dir(name);
    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../psao-scene/tests/data/CornellBox.glb"
    );
    let run = Command::new(env!("CARGO_BIN_EXE_psao"))
        .args([
            "bench",
            "--only-gltf",
            "--gltf",
            model,
            "--width",
            "64",
            "--height",
            "36",
            "--frames",
            "2",
            "--reference-rays",
            "8",
            "--point-rays",
            "8",
            "--densities",
            "0.002",
            "--rates",
            "30",
            "--radius",
            "60",
        ])
        .args(extra)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&run.stdout).into_owned() + &String::from_utf8_lossy(&run.stderr);
    let md = std::fs::read_to_string(out.join("bench.md")).unwrap_or_default();
    let _ = std::fs::remove_dir_all(&out);
    (run.status.success(), text, md)
}

/// The share of pixels covered that bench.md states.
fn coverage(md: &str) -> u32 {
    let at = md.find("% of pixels covered").expect("a coverage line");
    let digits: String = md[..at]
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    digits.parse().unwrap()
}

#[test]
fn bench_sees_a_room_from_inside_or_from_the_camera_it_is_given() {
    // No camera in the file: the automatic path walks round inside.
    let (ok, text, md) = cornell("cornell-auto", &[]);
    assert!(ok, "{text}");
    assert!(coverage(&md) >= 50, "{md}");
    // A fixed camera at the open front, looking at the back wall: all room.
    let (ok, text, md) = cornell("cornell-fixed", &["--camera", "-278,274,-60,-278,200,-559"]);
    assert!(ok, "{text}");
    assert!(coverage(&md) >= 90, "{md}");
    // A camera-path file that looks away from the room: refused, saying so.
    let file = std::env::temp_dir().join(format!("psao-away-{}.txt", std::process::id()));
    std::fs::write(
        &file,
        "fov 40\n0 -2000 0 0 -3000 0 0\n1 -2000 0 1 -3000 0 1\n",
    )
    .unwrap();
    let (ok, text, _) = cornell("cornell-away", &["--camera-path", file.to_str().unwrap()]);
    assert!(!ok && text.contains("sees none of the scene"), "{text}");
    let _ = std::fs::remove_file(&file);
}
