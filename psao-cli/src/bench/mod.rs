//! `psao bench`: accuracy against run time. For each scene and each
//! configuration (PSAO-N at several server rates, per-pixel RTAO at a few
//! rays per pixel, SAO) over frames of the scene's camera path: server and
//! client milliseconds per frame, bit rate, and RMSE / PSNR / SSIM / FLIP
//! against a per-pixel ray-traced reference. Writes a CSV, a markdown
//! table, charts and, for each frame `--image-frames` names (frame 0 by
//! default), the AO images and a side-by-side picture.

mod charts;
pub mod images;
mod measure;
mod model;
mod report;

use std::path::PathBuf;

use anyhow::Context as _;
use indicatif::{ProgressBar, ProgressStyle};
use psao_scene::{AoParams, PipelineConfig, Scene, load_scene_file, stage};

use crate::cmd::common::{EarlyServers, Embedded, MoversWholeArg};

pub use measure::{ImageFrames, Settings};

/// Where PSAO servers trace.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU tracer (obvhs).
    Cpu,
    /// wgpu ray queries (psao-gpu).
    Gpu,
}

/// Arguments of `psao bench`. Options whose default depends on `--full`
/// are `Option`s and say both defaults in their help; the others carry
/// their default for clap to print.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// The paper-sized run: 1280x720, 24 frames, a 512-ray reference,
    /// 192 rays per point, every density at every rate.
    #[arg(long)]
    full: bool,
    /// Scene files (glTF .gltf/.glb, or OBJ) to bench as well, repeatable
    /// (an object staged on a floor, a room seen from inside; with an
    /// automatic camera when the file has none) [default: none].
    #[arg(long = "gltf")]
    gltf: Vec<PathBuf>,
    /// The embedded scenes to bench, comma-separated: `default` (the
    /// codec demo's), `cesium-man` (a skinned figure on a floor), `hall`
    /// (207 instances: 160 sliding props, 4 walking figures; 5.1 million
    /// points at N = 2048 and every prop moving every tick: give it fewer
    /// densities, rates and rays, it takes long at the defaults).
    #[arg(
        long,
        value_delimiter = ',',
        value_enum,
        default_value = "default,cesium-man",
        hide_possible_values = true
    )]
    scenes: Vec<Embedded>,
    /// Only the scenes passed with --gltf (none of --scenes).
    #[arg(long)]
    only_gltf: bool,
    /// Image width [default: 320; with --full: 1280].
    #[arg(long)]
    width: Option<u32>,
    /// Image height [default: 180; with --full: 720].
    #[arg(long)]
    height: Option<u32>,
    /// Frames of the camera path to measure [default: 6; with --full: 24].
    #[arg(long)]
    frames: Option<u32>,
    /// Which measured frames to save as images: 0-based indices below
    /// --frames, comma-separated (0,2,5), or `all`. Frame 0's files are
    /// `SCENE-frame.png`, `SCENE-ao-*.png` and `SCENE-*.exr`; frame k's
    /// carry `-fk` after the scene's name (`SCENE-f2-frame.png`).
    #[arg(long, default_value = "0", value_parser = ImageFrames::parse)]
    image_frames: ImageFrames,
    /// Rays per pixel of the reference [default: 256; with --full: 512].
    #[arg(long)]
    reference_rays: Option<u32>,
    /// AO rays per PSAO point [default: 64; with --full: 192].
    #[arg(long)]
    point_rays: Option<u32>,
    /// AO radius R in scene units, for the reference, PSAO, RTAO and SAO
    /// alike; the default is the paper's (size it to the scene: a 7 cm
    /// model wants millimetres).
    #[arg(long, default_value_t = AoParams::default().radius)]
    radius: f32,
    /// PSAO densities N, points kept per square metre (the paper's N),
    /// comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "128,256,512,1024,2048")]
    densities: Vec<f32>,
    /// Server rates in Hz, comma-separated: every density runs at the
    /// first, the listed density nearest 1024 at the others (with --full:
    /// every density at every rate).
    #[arg(long, value_delimiter = ',', default_value = "60,30,15,5")]
    rates: Vec<u16>,
    /// Network delay in ms: a server tick's frame reaches the client one
    /// server period plus this after its scene time.
    #[arg(long, default_value_t = 0.0)]
    network_ms: f32,
    /// Where PSAO servers trace their AO rays: `cpu` (obvhs) or `gpu`
    /// (wgpu ray queries; build with `--features gpu`).
    // The values are named above: listing them with their descriptions
    // would switch `--help` to its long layout.
    #[arg(long, value_enum, default_value_t = Backend::Cpu, hide_possible_values = true)]
    backend: Backend,
    /// Output folder.
    #[arg(long, default_value = "bench-out")]
    out: PathBuf,
    /// The camera of the scenes given with --gltf (the default and
    /// CesiumMan scenes keep theirs).
    #[command(flatten)]
    camera: crate::cmd::common::CameraArgs,
    /// Look at the --gltf scenes with the automatic camera path even where
    /// a file has a camera of its own (whose framing is its author's: the
    /// Cameras sample's covers about a fifth of the picture).
    #[arg(long, conflicts_with_all = ["camera", "camera_path"])]
    auto_camera: bool,
    /// Trace buried points like any other (the baseline) instead of giving
    /// them their visible neighbours' AO.
    #[arg(long)]
    no_fill_buried: bool,
    /// Keep deforming (skinned, morphing) instances' points in posed space,
    /// moved and re-sent with every pose (point format 0: the baseline),
    /// instead of in their mesh's bind space (point format 1).
    #[arg(long)]
    posed_deforming: bool,
    /// Drop the points a full cell has no slot for (the baseline) instead
    /// of continuing the cell in an overflow chain (spec/wire-format.md
    /// 7.4).
    #[arg(long)]
    no_overflow: bool,
    /// Keep sample elimination's points alone (the baseline) instead of
    /// filling the gaps it leaves on strips thinner than the point spacing
    /// and spawning a few points on meshes smaller than two points' area.
    #[arg(long)]
    no_gap_fill: bool,
    /// Servers trace each tick's scene at the tick's own time (the
    /// baseline: what a client holds is a period or more behind what it
    /// draws) instead of one period plus --network-ms ahead, the time the
    /// tick's frame is shown.
    #[arg(long)]
    no_lead: bool,
    /// Servers send a point whose AO stopped changing (or that motion has
    /// left) once it is this many 1/255 steps from what clients hold, below
    /// the send threshold (0: never, the baseline: the threshold's worth of
    /// error stays behind where motion passed and left AO short of open).
    #[arg(long, default_value_t = PipelineConfig::default().settle_steps)]
    settle_steps: u8,
    /// Add, per density, a PSAO configuration whose server traces within
    /// this ray budget (`auto`: what 80% of the period affords on this
    /// machine; or a number of rays per tick), beside the unbudgeted ones;
    /// it makes early decisions unless --no-early-decisions
    #[arg(long, value_parser = crate::cmd::common::parse_ray_budget)]
    ray_budget: Option<psao_scene::RayBudget>,
    /// Under --ray-budget, the most ticks a point waits while the budget
    /// affords it.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1000))]
    max_wait: u32,
    /// Under --ray-budget, the most ticks the bound on waiting rises to
    /// when demand exceeds the budget (at least --max-wait).
    #[arg(long, default_value_t = PipelineConfig::default().max_wait_limit, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    max_wait_limit: u32,
    /// Servers re-trace every ray of a point motion reached (the baseline)
    /// instead of only the reached rays, keeping the others' scores (the
    /// frames are the same unbudgeted; under --ray-budget a point then
    /// costs all its rays).
    #[arg(long)]
    no_ray_reuse: bool,
    /// Cast a point's rays even where no triangle lies within their reach
    /// (the baseline: such a point is otherwise known open without a ray;
    /// the frames are the same, and so are a fixed --ray-budget's
    /// choices).
    #[arg(long)]
    no_skip_open: bool,
    /// With --backend gpu, servers cast single rays, keeping ray scores as
    /// on the CPU (ray reuse and early decisions follow the CPU's rules),
    /// instead of tracing every ray of each point they trace (the
    /// default: on lavapipe it held more PSNR under an automatic budget).
    #[arg(long)]
    gpu_single_rays: bool,
    /// The PSAO client weighs every candidate point by eq. 2-3 alone
    /// (spec/wire-format.md 7.3, the paper's reconstruction), instead of
    /// also leaving out the points its view shows hidden behind another
    /// surface that faces the pixel (7.3.1, the default since 2026-12-06:
    /// more accurate where thin parts stand on surfaces, at 1.06-1.50x the
    /// client time of eq. 2-4 in BENCHMARKS.md's runs, issue 15).
    #[arg(long, conflicts_with = "hidden_test")]
    no_hidden_test: bool,
    /// The hidden-candidate test of spec/wire-format.md 7.3.1: the default
    /// (kept so that commands written before it was the default run as
    /// they did).
    #[arg(long)]
    hidden_test: bool,
    /// Under --ray-budget, trace a moving instance's own points every tick
    /// it moves, whatever the budget (no AO lagging its transform).
    #[arg(long)]
    movers_every_frame: bool,
    /// Under --ray-budget, trace a rigid moving part whole at one pose
    /// (on the CPU, over several ticks against a snapshot of the scene
    /// where it does not fit a tick's budget), its transform held back with its points
    /// while they wait: `auto` (the default) for those whose own AO
    /// changes as they move and that do not turn in place, while together
    /// they cost at most half the budget; `on` for every such part (`--movers-whole` alone); `off`
    /// for none.
    #[arg(long, value_enum, default_value_t = MoversWholeArg::Auto, num_args = 0..=1, default_missing_value = "on")]
    movers_whole: MoversWholeArg,
    /// Under a budget, where the scene's animations loop together within
    /// 20 s, remember each traced point's AO by the moment of the loop, in
    /// about this many MiB (0: off); in later rounds a point whose AO at
    /// that moment would not be sent against what clients hold ranks below
    /// the points that changed (it orders what is traced and verifies
    /// waiting points, see --no-loop-verify; nothing is sent from it, and
    /// a placement by MOVE_INSTANCE drops it)
    #[arg(long, default_value_t = psao_scene::PipelineConfig::default().loop_memory_bytes >> 20, value_parser = clap::value_parser!(u64).range(0..=1 << 20))]
    loop_memory_mib: u64,
    /// Keep the loop memory from verifying waiting points (by default,
    /// where the same time of the loop poses the scene alike, a waiting
    /// point whose AO traced at that time would not be sent has its wait
    /// started again instead of being traced when due)
    #[arg(long)]
    no_loop_verify: bool,
    /// Under --ray-budget, once demand has raised the bound on waiting,
    /// plan a static point that waited a few ticks once, when the budget
    /// takes it, against what moved in every tick it waited, instead of
    /// tracing it in full (fewer rays a point: better at a fixed budget;
    /// under `auto` no gain is resolved on the default scene)
    #[arg(long)]
    plan_late: bool,
    /// Every PSAO server makes early decisions, the unbudgeted ones too
    /// (by default only the budgeted ones do): a moving instance's point
    /// stops casting rays once its AO is known, to 3 standard errors, to
    /// stay within the send threshold of what clients hold
    #[arg(long, conflicts_with = "no_early_decisions")]
    early_decisions: bool,
    /// No PSAO server makes early decisions, the budgeted ones neither
    #[arg(long)]
    no_early_decisions: bool,
}

impl BenchArgs {
    /// The settings these arguments ask for (not yet validated): `--full`
    /// or the quick defaults, with every given option over them.
    pub fn settings(&self) -> Settings {
        let mut settings = if self.full {
            Settings::full()
        } else {
            Settings::quick()
        };
        if let Some(w) = self.width {
            settings.width = w;
        }
        if let Some(h) = self.height {
            settings.height = h;
        }
        if let Some(f) = self.frames {
            settings.frames = f;
        }
        if let Some(r) = self.reference_rays {
            settings.reference_rays = r;
        }
        if let Some(r) = self.point_rays {
            settings.point_rays = r;
        }
        settings.radius = self.radius;
        settings.densities = self.densities.clone();
        settings.rates = self.rates.clone();
        settings.network_ms = self.network_ms;
        settings.backend = self.backend;
        settings.image_frames = self.image_frames.clone();
        settings.fill_buried = !self.no_fill_buried;
        settings.bind_space = !self.posed_deforming;
        settings.overflow = !self.no_overflow;
        settings.fill_gaps = !self.no_gap_fill;
        settings.lead = !self.no_lead;
        settings.settle_steps = self.settle_steps;
        settings.budget = self.ray_budget;
        settings.max_wait = self.max_wait;
        settings.max_wait_limit = self.max_wait_limit;
        settings.ray_reuse = !self.no_ray_reuse;
        settings.skip_open = !self.no_skip_open;
        settings.gpu_single_rays = self.gpu_single_rays;
        settings.hidden_test = !self.no_hidden_test;
        settings.movers_every_step = self.movers_every_frame;
        settings.movers_whole = self.movers_whole.into();
        settings.plan_late = self.plan_late;
        settings.loop_memory_bytes = self.loop_memory_mib << 20;
        settings.loop_verify = !self.no_loop_verify;
        settings.early = EarlyServers::from_flags(self.early_decisions, self.no_early_decisions);
        settings
    }
}

/// Runs the bench and writes its outputs.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    let settings = args.settings();
    settings.validate()?;
    let mut scenes: Vec<(String, Scene)> = Vec::new();
    if !args.only_gltf {
        let mut seen = Vec::new();
        for &e in &args.scenes {
            if seen.contains(&e) {
                continue;
            }
            seen.push(e);
            scenes.push((e.name().into(), e.scene()));
        }
    }
    let camera = args.camera.path()?;
    for path in &args.gltf {
        // The error names the file already.
        let mut scene = load_scene_file(path)?;
        if let Some(c) = &camera {
            scene.camera = Some(c.clone());
        } else if args.auto_camera {
            scene.camera = None;
        }
        let scene = stage(scene)?;
        let name = path
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "gltf".into());
        scenes.push((name, scene));
    }
    if scenes.is_empty() {
        anyhow::bail!("no scene to bench: --only-gltf needs --gltf FILE");
    }
    let densest = settings.densities.iter().copied().fold(0.0, f32::max);
    for (name, scene) in &scenes {
        for w in crate::cmd::common::scale_warnings(scene, densest, settings.radius)? {
            eprintln!("warning: {name}: {w}");
        }
    }
    // Before any work: every scene has a camera path giving each frame
    // --image-frames asks for (frame times that coincide count once).
    for (name, scene) in &scenes {
        let path = scene
            .camera
            .as_ref()
            .with_context(|| format!("{name}: the scene has no camera path"))?;
        let measured = measure::measured_frames(path.duration(), settings.frames);
        if let Some(k) = settings.image_frames.out_of_range(measured) {
            anyhow::bail!(
                "--image-frames {k} is out of range for {name}: its {:.2} s camera path gives {measured} distinct frames of the {} asked for",
                path.duration(),
                settings.frames
            );
        }
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
        "psao bench: {} scene(s), {}x{}, {} frames, reference {} rays/pixel, {} rays/point; images of frame(s) {}; output in {}",
        scenes.len(),
        settings.width,
        settings.height,
        settings.frames,
        settings.reference_rays,
        settings.point_rays,
        settings.image_frames,
        args.out.display()
    );
    let mut results = Vec::new();
    for (name, scene) in scenes {
        let r = measure::measure_scene(&name, scene, &settings, &bar)?;
        bar.set_message(format!("{name}: writing images and charts"));
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

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    /// `psao bench`'s arguments alone.
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: BenchArgs,
    }

    fn settings(args: &[&str]) -> Settings {
        let cli = Cli::try_parse_from(std::iter::once("bench").chain(args.iter().copied()))
            .unwrap_or_else(|e| panic!("{args:?}: {e}"));
        cli.args.settings()
    }

    /// The defaults `--help` prints are the ones the bench runs with.
    #[test]
    fn defaults_are_the_quick_and_full_settings() {
        for (args, want) in [
            (&[][..], Settings::quick()),
            (&["--full"][..], Settings::full()),
        ] {
            let got = settings(args);
            assert_eq!(
                (got.width, got.height, got.frames),
                (want.width, want.height, want.frames),
                "{args:?}"
            );
            assert_eq!(
                (got.reference_rays, got.point_rays, got.cross),
                (want.reference_rays, want.point_rays, want.cross)
            );
            assert_eq!(got.densities, want.densities);
            assert_eq!(got.rates, want.rates);
            assert_eq!(got.radius, want.radius);
            assert_eq!(got.network_ms, want.network_ms);
            assert_eq!(got.lead, want.lead);
            assert_eq!(got.settle_steps, want.settle_steps);
            assert_eq!(got.image_frames, ImageFrames::List(vec![0]));
            assert_eq!(got.backend, Backend::Cpu);
        }
    }

    /// The budgeted servers make early decisions by default, the
    /// unbudgeted ones (the baseline) not; `--early-decisions` has every
    /// server make them, `--no-early-decisions` none; not both.
    #[test]
    fn budgeted_servers_make_early_decisions_unless_told_otherwise() {
        assert_eq!(settings(&[]).early, EarlyServers::Budgeted);
        assert_eq!(settings(&["--early-decisions"]).early, EarlyServers::All);
        assert_eq!(
            settings(&["--no-early-decisions"]).early,
            EarlyServers::None
        );
        assert!(
            Cli::try_parse_from(["bench", "--early-decisions", "--no-early-decisions"]).is_err()
        );
        // (Which servers each makes them on: `EarlyServers::make_them`'s
        // test, in cmd/common.rs.)
    }

    /// `--loop-memory-mib` is the pipeline's default (64 MiB) unless
    /// given; 0 turns the memory off; a negative or huge size is refused.
    #[test]
    fn the_loop_memory_is_64_mib_by_default_and_0_turns_it_off() {
        assert_eq!(settings(&[]).loop_memory_bytes, 64 << 20);
        assert_eq!(
            settings(&[]).loop_memory_bytes,
            psao_scene::PipelineConfig::default().loop_memory_bytes
        );
        assert_eq!(settings(&["--loop-memory-mib", "0"]).loop_memory_bytes, 0);
        assert!(settings(&[]).loop_verify);
        assert!(!settings(&["--no-loop-verify"]).loop_verify);
        assert_eq!(
            settings(&["--loop-memory-mib", "3"]).loop_memory_bytes,
            3 << 20
        );
        for bad in ["-1", "2000000", "lots"] {
            assert!(
                Cli::try_parse_from(["bench", "--loop-memory-mib", bad]).is_err(),
                "{bad}"
            );
        }
    }

    /// `--movers-whole` is `auto` by default, `on` alone (as before it
    /// took a value), and takes `off`, `on` or `auto`.
    #[test]
    fn movers_whole_is_auto_by_default_and_on_alone() {
        use psao_scene::MoversWhole;
        assert_eq!(settings(&[]).movers_whole, MoversWhole::Auto);
        assert_eq!(settings(&["--movers-whole"]).movers_whole, MoversWhole::On);
        assert_eq!(
            settings(&["--movers-whole", "--frames", "3"]).movers_whole,
            MoversWhole::On
        );
        for (v, want) in [
            ("off", MoversWhole::Off),
            ("on", MoversWhole::On),
            ("auto", MoversWhole::Auto),
        ] {
            assert_eq!(settings(&["--movers-whole", v]).movers_whole, want);
        }
        assert!(Cli::try_parse_from(["bench", "--movers-whole", "always"]).is_err());
    }

    #[test]
    fn the_automatic_camera_excludes_a_given_one() {
        let parse = |args: &[&str]| {
            Cli::try_parse_from(std::iter::once("bench").chain(args.iter().copied()))
                .map(|c| c.args.auto_camera)
        };
        assert!(parse(&["--auto-camera"]).unwrap());
        assert!(!parse(&[]).unwrap());
        assert!(parse(&["--auto-camera", "--camera", "0,1,2,0,0,0"]).is_err());
        assert!(parse(&["--auto-camera", "--camera-path", "p.txt"]).is_err());
    }

    #[test]
    fn given_options_override_the_defaults() {
        let s = settings(&[
            "--full",
            "--width",
            "64",
            "--frames",
            "3",
            "--densities",
            "8,16",
            "--rates",
            "30",
            "--image-frames",
            "2,0",
        ]);
        assert_eq!((s.width, s.height, s.frames), (64, 720, 3));
        assert_eq!(s.densities, vec![8.0, 16.0]);
        assert_eq!(s.rates, vec![30]);
        assert_eq!(s.image_frames, ImageFrames::List(vec![0, 2]));
        assert!(s.validate().is_ok());
        let s = settings(&["--frames", "3", "--image-frames", "3"]);
        let e = s.validate().expect_err("frame 3 of 3").to_string();
        assert!(e.contains("--image-frames 3"), "{e}");
        let e = Cli::try_parse_from(["bench", "--image-frames", "1,two"])
            .err()
            .expect("`two` is no index")
            .to_string();
        assert!(e.contains("`two` is not a frame index"), "{e}");
    }
}
