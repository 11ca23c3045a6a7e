//! `psao bench`: accuracy against run time. For each scene and each
//! configuration (PSAO-N at several server rates, per-pixel RTAO at a few
//! rays per pixel, SAO) over frames of the scene's camera path: server and
//! client milliseconds per frame, bit rate, and RMSE / PSNR / SSIM / FLIP
//! against a per-pixel ray-traced reference. Writes a CSV, a markdown
//! table, charts and a side-by-side image of one frame.

mod charts;
pub mod images;
mod measure;
mod model;
mod report;

use std::path::PathBuf;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressStyle};
use psao_scene::{Scene, cesium_man_scene, default_scene, load_scene_file, stage};

pub use measure::Settings;

/// Where PSAO servers trace.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU tracer (obvhs).
    Cpu,
    /// wgpu ray queries (psao-gpu).
    Gpu,
}

/// Arguments of `psao bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// The paper-sized run: 1280x720, 24 frames, a 512-ray reference,
    /// 192 rays per point, every density at every rate.
    #[arg(long)]
    full: bool,
    /// Scene files (glTF .gltf/.glb, or OBJ) to bench as well (each staged on a floor, with an
    /// orbiting camera when it has no camera path).
    #[arg(long = "gltf")]
    gltf: Vec<PathBuf>,
    /// Only the scenes passed with --gltf (skip the default and CesiumMan
    /// scenes).
    #[arg(long)]
    only_gltf: bool,
    /// Image width (default 320, --full 1280).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (default 180, --full 720).
    #[arg(long)]
    height: Option<u32>,
    /// Frames of the camera path to measure (default 6, --full 24).
    #[arg(long)]
    frames: Option<u32>,
    /// Rays per pixel of the reference (default 256, --full 512).
    #[arg(long)]
    reference_rays: Option<u32>,
    /// AO rays per PSAO point (default 64, --full 192).
    #[arg(long)]
    point_rays: Option<u32>,
    /// AO radius R in scene units, for the reference, PSAO, RTAO and SAO
    /// alike (default 0.6, the paper's; size it to the scene: a 7 cm model
    /// wants millimetres).
    #[arg(long)]
    radius: Option<f32>,
    /// PSAO densities N, points kept per square metre (the paper's N).
    #[arg(long, value_delimiter = ',')]
    densities: Option<Vec<f32>>,
    /// Server rates in Hz.
    #[arg(long, value_delimiter = ',')]
    rates: Option<Vec<u16>>,
    /// Network delay in ms: a server tick's frame reaches the client one
    /// server period plus this after its scene time.
    #[arg(long)]
    network_ms: Option<f32>,
    /// Where PSAO servers trace their AO rays: `cpu` (obvhs) or `gpu`
    /// (wgpu ray queries; build with `--features gpu`).
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
    backend: Backend,
    /// Output folder.
    #[arg(long, default_value = "bench-out")]
    out: PathBuf,
}

/// Runs the bench and writes its outputs.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let mut settings = if args.full {
        Settings::full()
    } else {
        Settings::quick()
    };
    if let Some(w) = args.width {
        settings.width = w;
    }
    if let Some(h) = args.height {
        settings.height = h;
    }
    if let Some(f) = args.frames {
        settings.frames = f;
    }
    if let Some(r) = args.reference_rays {
        settings.reference_rays = r;
    }
    if let Some(r) = args.point_rays {
        settings.point_rays = r;
    }
    if let Some(r) = args.radius {
        settings.radius = r;
    }
    if let Some(d) = args.densities {
        settings.densities = d;
    }
    if let Some(r) = args.rates {
        settings.rates = r;
    }
    if let Some(n) = args.network_ms {
        settings.network_ms = n;
    }
    settings.backend = args.backend;
    settings.validate()?;
    let mut scenes: Vec<(String, Scene)> = Vec::new();
    if !args.only_gltf {
        scenes.push(("default".into(), default_scene()));
        scenes.push(("cesium-man".into(), cesium_man_scene()));
    }
    for path in &args.gltf {
        // The error names the file already.
        let scene = load_scene_file(path).and_then(stage)?;
        let name = path
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "gltf".into());
        scenes.push((name, scene));
    }
    if scenes.is_empty() {
        anyhow::bail!("no scene to bench: --only-gltf needs --gltf FILE");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let units: u64 = scenes.len() as u64 * settings.units_per_scene();
    let bar = ProgressBar::new(units);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg}")?
            .progress_chars("=> "),
    );
    eprintln!(
        "psao bench: {} scene(s), {}x{}, {} frames, reference {} rays/pixel, {} rays/point; output in {}",
        scenes.len(),
        settings.width,
        settings.height,
        settings.frames,
        settings.reference_rays,
        settings.point_rays,
        args.out.display()
    );
    let mut results = Vec::new();
    for (name, scene) in scenes {
        let r = measure::measure_scene(&name, scene, &settings, &bar)?;
        images::write_scene_images(&args.out, &r).with_context(|| name.to_string())?;
        charts::write_charts(&args.out, &r).with_context(|| format!("{name}: charts"))?;
        results.push(r);
    }
    bar.finish_and_clear();
    let files = report::write(&args.out, &settings, &results)?;
    println!("{}", report::markdown(&settings, &results));
    println!("wrote {}", files.join(", "));
    Ok(())
}
