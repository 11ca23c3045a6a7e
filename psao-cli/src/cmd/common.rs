//! What several subcommands share: where a client connects and how it
//! trusts the server, scene loading, the pipeline settings, the live
//! status line and the process's CPU time.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context as _, bail};
use psao_proto::tls::parse_fingerprint;
use psao_proto::{ServerStats, Trust};
use psao_scene::{
    CameraPath, DEFAULT_FOV_DEGREES, Pipeline, PipelineConfig, RayBudget, Scene, SetupProgress,
    SetupStage, default_scene, load_scene_file,
};

/// Where the viewer looks from: a fixed camera, a camera-path file, or
/// (neither given) the scene's own camera, else an automatic one.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct CameraArgs {
    /// A fixed camera, EYE,TARGET: six numbers `ex,ey,ez,tx,ty,tz` in
    /// scene units [default: the scene's camera (a glTF camera or its
    /// animated node), else an automatic path: an orbit round an object,
    /// a walk round inside a room].
    #[arg(long, value_parser = parse_eye_target, conflicts_with = "camera_path",
          allow_hyphen_values = true, value_name = "EYE,TARGET")]
    pub camera: Option<[f32; 6]>,
    /// A camera-path file: one key per line, `time ex ey ez tx ty tz`
    /// (seconds, scene units; spaces or commas), an optional `fov DEGREES`
    /// line, `#` comments [default: as --camera].
    #[arg(long, value_name = "FILE")]
    pub camera_path: Option<PathBuf>,
    /// Vertical field of view of --camera, degrees.
    #[arg(long, default_value_t = DEFAULT_FOV_DEGREES, requires = "camera")]
    pub fov: f32,
}

impl CameraArgs {
    /// The camera path these arguments give, if any (read and checked).
    pub fn path(&self) -> anyhow::Result<Option<CameraPath>> {
        if let Some(v) = self.camera {
            if !(self.fov > 0.0 && self.fov < 180.0) {
                bail!("--fov {} is not in (0, 180) degrees", self.fov);
            }
            let eye = glam::Vec3::new(v[0], v[1], v[2]);
            let target = glam::Vec3::new(v[3], v[4], v[5]);
            return Ok(Some(
                CameraPath::fixed(eye, target, self.fov.to_radians()).context("--camera")?,
            ));
        }
        match &self.camera_path {
            Some(p) => Ok(Some(CameraPath::load(p)?)),
            None => Ok(None),
        }
    }
}

/// Points kept above which [`scale_warnings`] warns.
pub const MANY_POINTS: f64 = 20e6;

/// What a user should hear before a long setup: a `density` (points kept
/// per square unit) that gives more than [`MANY_POINTS`] points (a scene
/// in centimetres or millimetres read as metres), or an AO `radius` above
/// half the scene's largest extent (everything occludes everything) or
/// below 1/10,000 of it (AO open everywhere). Each line names the scene's
/// size and the option to change.
pub fn scale_warnings(scene: &Scene, density: f32, radius: f32) -> anyhow::Result<Vec<String>> {
    let tris = scene.world_triangles()?;
    let area: f64 = tris
        .iter()
        .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() as f64 * 0.5)
        .sum();
    let (lo, hi) = tris.iter().flatten().fold(
        (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    );
    let extent = (hi - lo).max_element().max(0.0);
    let mut out = Vec::new();
    let points = area * density as f64;
    if points > MANY_POINTS {
        out.push(format!(
            "--density {density} gives about {:.1} million points: the scene is {extent:.4} units across and {area:.4e} square units of surface (are its units metres?); a lower --density sets up faster",
            points / 1e6
        ));
    }
    if extent > 0.0 && radius > 0.5 * extent {
        out.push(format!(
            "AO radius {radius} is more than half the scene ({extent:.4} units across): everything occludes everything; try --radius {:.3}",
            extent / 10.0
        ));
    } else if extent > 0.0 && radius < 1e-4 * extent {
        out.push(format!(
            "AO radius {radius} is below 1/10,000 of the scene ({extent:.4} units across): AO is open nearly everywhere; try --radius {:.3}",
            extent / 100.0
        ));
    }
    Ok(out)
}

/// Parses `ex,ey,ez,tx,ty,tz`.
fn parse_eye_target(s: &str) -> Result<[f32; 6], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|w| {
            w.trim()
                .parse::<f32>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("`{}` is not a finite number", w.trim()))
        })
        .collect::<Result<_, _>>()?;
    <[f32; 6]>::try_from(v.as_slice()).map_err(|_| {
        format!(
            "{} numbers; expected six, EYE,TARGET: ex,ey,ez,tx,ty,tz",
            v.len()
        )
    })
}

/// Where a client connects and how it trusts the server.
#[derive(clap::Args)]
pub struct ServerArgs {
    /// The server's address, IP:port (required, unless the command
    /// subscribes through a relay instead).
    #[arg(long)]
    pub connect: Option<SocketAddr>,
    /// SHA-256 fingerprint of the server's certificate (as `psao serve`
    /// prints it), or of the relay's with --subscribe; this or --ca is
    /// needed.
    #[arg(long, conflicts_with = "ca")]
    pub fingerprint: Option<String>,
    /// PEM file of certificates to trust instead of --fingerprint.
    #[arg(long)]
    pub ca: Option<PathBuf>,
    /// With --ca: the name the server's certificate must carry.
    #[arg(long, requires = "ca", default_value = "localhost")]
    pub name: String,
    /// Stop after this many seconds [default: until the server closes].
    #[arg(long)]
    pub seconds: Option<f32>,
}

impl ServerArgs {
    /// The server's address (--connect).
    pub fn addr(&self) -> anyhow::Result<SocketAddr> {
        self.connect
            .context("give --connect IP:PORT (the address `psao serve` prints)")
    }

    /// How the client trusts the server: a pinned fingerprint, or roots
    /// from a PEM file.
    pub fn trust(&self) -> anyhow::Result<Trust> {
        match (&self.fingerprint, &self.ca) {
            (Some(f), _) => Ok(Trust::Fingerprint(parse_fingerprint(f)?)),
            (None, Some(ca)) => Ok(Trust::Roots {
                roots: read_roots(ca)?,
                name: self.name.clone(),
            }),
            (None, None) => bail!("give --fingerprint (printed by `psao serve`) or --ca"),
        }
    }
}

/// A duration of `s` seconds, clamped to [0, 10^7] (NaN reads as 0).
pub fn seconds_of(s: f32) -> Duration {
    Duration::from_secs_f32(if s.is_nan() { 0.0 } else { s.clamp(0.0, 1e7) })
}

/// Parses a ray budget argument: `auto` (the rays 80% of a frame's period
/// affords at the measured cost of a ray), `none` (no limit: the
/// baseline) or a number of rays per frame.
pub fn parse_ray_budget(s: &str) -> Result<RayBudget, String> {
    match s {
        "auto" => Ok(RayBudget::Auto { share: 0.8 }),
        "none" => Ok(RayBudget::Unlimited),
        n if n.starts_with("auto:") => match n["auto:".len()..].parse::<f32>() {
            Ok(share) if share > 0.0 && share <= 1.0 => Ok(RayBudget::Auto { share }),
            _ => Err(format!(
                "expected auto:SHARE with a share of the frame period in (0, 1], not {n:?}"
            )),
        },
        n => n.parse::<u64>().map(RayBudget::Rays).map_err(|_| {
            format!("expected auto, auto:SHARE, none or a number of rays per frame, not {n:?}")
        }),
    }
}

/// Which PSAO servers make early decisions
/// ([`PipelineConfig::early`](psao_scene::PipelineConfig::early)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EarlyServers {
    /// None: every point a server chooses casts all its rays.
    None,
    /// The budgeted ones (the default); the unbudgeted servers, the
    /// baseline, trace every point in full.
    Budgeted,
    /// Every one, the unbudgeted ones too.
    All,
}

impl EarlyServers {
    /// What `--early-decisions` and `--no-early-decisions` ask for (clap
    /// refuses both): every server, none, or by default the budgeted ones.
    pub fn from_flags(early: bool, no_early: bool) -> EarlyServers {
        match (early, no_early) {
            (_, true) => EarlyServers::None,
            (true, false) => EarlyServers::All,
            (false, false) => EarlyServers::Budgeted,
        }
    }

    /// Whether a server traced under `budget` makes early decisions (an
    /// unlimited budget is the baseline's: not budgeted).
    pub fn make_them(self, budget: RayBudget) -> bool {
        match self {
            EarlyServers::None => false,
            EarlyServers::Budgeted => budget != RayBudget::Unlimited,
            EarlyServers::All => true,
        }
    }
}

/// The ray budget options of the commands that run a server.
#[derive(clap::Args, Clone, Debug)]
pub struct BudgetArgs {
    /// Rays the server may trace per frame: `auto` (what 80% of the frame
    /// period affords at the measured cost of a ray, so the server holds
    /// its rate; `auto:0.7` for 70%), `none` (every point motion reaches,
    /// in its frame: the baseline) or a number of rays. Points past it wait for a later
    /// frame, the most reached first.
    #[arg(long, default_value = "auto", value_parser = parse_ray_budget)]
    pub ray_budget: RayBudget,
    /// Under a budget, the most frames a point waits before it is traced
    /// whatever the budget, while the budget affords it.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub max_wait: u32,
    /// Under a budget, the most frames the bound on waiting rises to when
    /// the points that reach it alone cost more than a frame's budget (at
    /// least --max-wait; the status line shows the bound in force).
    #[arg(long, default_value_t = PipelineConfig::default().max_wait_limit, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub max_wait_limit: u32,
    /// Under a budget, trace a moving instance's own points in every
    /// frame it moves, whatever the budget (which then holds only the
    /// static points around it): no AO lagging its transform, at the price
    /// of frames over the budget where movers alone exceed it.
    #[arg(long)]
    pub movers_every_frame: bool,
    /// Under a budget, trace a rigid moving part whole at one pose (over
    /// several frames against a snapshot of the scene on the CPU where it
    /// does not fit a frame's budget), and hold the transform clients hold back
    /// with its points while they wait (occlusion stays where it was
    /// traced, as from a slower server, instead of sliding with the part):
    /// `auto` (the default) for those whose own AO changes as they move
    /// (at least 10% of their traced points change enough to be sent) and
    /// that do not turn in place (as a wheel on its axle), while together
    /// they cost at most half the budget; `on` for every
    /// such part (`--movers-whole` alone); `off` for none.
    #[arg(long, value_enum, default_value_t = MoversWholeArg::Auto, num_args = 0..=1, default_missing_value = "on")]
    pub movers_whole: MoversWholeArg,
    /// Under a budget, where the scene's animations loop together within
    /// 20 s, remember each traced point's AO by the moment of the loop, in
    /// about this many MiB (0: off); in later rounds a point whose AO at
    /// that moment would not be sent against what clients hold ranks below
    /// the points that changed (it orders what is traced and verifies
    /// waiting points, see --no-loop-verify; nothing is sent from it, and
    /// a placement by MOVE_INSTANCE drops it)
    #[arg(long, default_value_t = PipelineConfig::default().loop_memory_bytes >> 20, value_parser = clap::value_parser!(u64).range(0..=1 << 20))]
    pub loop_memory_mib: u64,
    /// Keep the loop memory from verifying waiting points (by default,
    /// where the same time of the loop poses the scene alike, a waiting
    /// point whose AO traced at that time would not be sent has its wait
    /// started again instead of being traced when due)
    #[arg(long)]
    pub no_loop_verify: bool,
    /// Early decisions even without a budget (`--ray-budget none`); under
    /// a budget they are made by default. A moving instance's point stops
    /// casting rays once its AO is known, to 3 standard errors, to stay
    /// within the send threshold of what clients hold (nothing to send); a
    /// point that goes on is traced in full. Fewer rays on moving scenes,
    /// for rare updates sent a few frames late (BENCHMARKS.md measures
    /// both); moving points' kept ray scores take up to 64 MiB more (and 4-8
    /// bytes a point of the moving instances). Not made while
    /// --settle-steps is set, nor below 8 rays a point
    #[arg(long, conflicts_with = "no_early_decisions")]
    pub early_decisions: bool,
    /// No early decisions under a budget either: every moving point chosen
    /// casts all its rays
    #[arg(long)]
    pub no_early_decisions: bool,
}

impl BudgetArgs {
    /// Sets the budget in `config`, and early decisions: by default under
    /// a budget, not without one (the baseline).
    pub fn apply(&self, config: &mut PipelineConfig) {
        config.budget = self.ray_budget;
        config.max_wait = self.max_wait;
        config.max_wait_limit = self.max_wait_limit.max(self.max_wait);
        config.movers_every_step = self.movers_every_frame;
        config.movers_whole = self.movers_whole.into();
        config.loop_memory_bytes = self.loop_memory_mib << 20;
        config.loop_verify = !self.no_loop_verify;
        config.early = EarlyServers::from_flags(self.early_decisions, self.no_early_decisions)
            .make_them(config.budget)
            .then(psao_scene::EarlyDecisions::default);
    }
}

/// How a server keeps what clients hold current: how far ahead of its
/// clock it poses the scene ([`PipelineConfig::lead`]) and settling
/// ([`PipelineConfig::settle_steps`]).
#[derive(clap::Args, Clone, Debug)]
pub struct LeadArgs {
    /// Milliseconds the server poses the scene's animation ahead of each
    /// frame's tick, so that a frame shows the pose its clients draw when
    /// it arrives: `auto` (one frame period, the time a frame takes to be
    /// traced and sent), or a number (add the network's delay; 0: the
    /// tick's own pose, a period or more behind on the client).
    #[arg(long, default_value = "auto", value_parser = parse_lead)]
    pub lead_ms: Lead,
    /// Send a point whose AO stopped changing (or that motion has left)
    /// once it is this many 1/255 steps from what clients hold, below the
    /// send threshold (0: never; a point that comes out fully open is sent
    /// anyway). Costs bit rate for little on the bench's animated scenes
    /// (BENCHMARKS.md).
    #[arg(long, default_value_t = PipelineConfig::default().settle_steps)]
    pub settle_steps: u8,
}

/// A `--lead-ms` value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lead {
    /// One frame period.
    Auto,
    /// This many milliseconds.
    Millis(f32),
}

/// Parses `--lead-ms`: `auto` or milliseconds in [0, 10000].
pub fn parse_lead(s: &str) -> Result<Lead, String> {
    if s == "auto" {
        return Ok(Lead::Auto);
    }
    match s.parse::<f32>() {
        Ok(ms) if (0.0..=10_000.0).contains(&ms) => Ok(Lead::Millis(ms)),
        _ => Err(format!(
            "expected auto or milliseconds in [0, 10000], not {s:?}"
        )),
    }
}

impl LeadArgs {
    /// The lead in seconds at `rate` frames a second.
    pub fn seconds(&self, rate: u16) -> f32 {
        match self.lead_ms {
            Lead::Auto => 1.0 / rate.max(1) as f32,
            Lead::Millis(ms) => ms / 1e3,
        }
    }

    /// Sets the lead (at `rate` frames a second) and settling in `config`.
    pub fn apply(&self, config: &mut PipelineConfig, rate: u16) {
        config.lead = self.seconds(rate);
        config.settle_steps = self.settle_steps;
    }
}

/// The pipeline settings of `--density`, `--rays` and `--radius`. Every
/// command's `--density` counts points kept per square metre, the paper's
/// N (as `psao bench --densities` does); the pipeline spawns twice as many
/// and keeps half. A radius that is not finite and positive is refused
/// when the pipeline is built.
pub fn pipeline_config(density: f32, rays: u32, radius: f32) -> PipelineConfig {
    let mut config = PipelineConfig::with_density_and_rays(2.0 * density, rays);
    config.ao.radius = radius;
    config
}

/// Sets up a pipeline over `scene` with a progress bar on standard error
/// (points and grids per instance, then the first trace per point; drawn
/// only on a terminal).
pub fn pipeline_with_progress(scene: Scene, config: PipelineConfig) -> anyhow::Result<Pipeline> {
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:>14} [{bar:30}] {human_pos}/{human_len} ({elapsed}, {eta} left)",
        )?
        .progress_chars("=> "),
    );
    let pipeline = Pipeline::with_progress(scene, config, None, &|p: SetupProgress| {
        let what = match p.stage {
            SetupStage::Points => "points, grids",
            SetupStage::Buried => "buried points",
            _ => "first trace",
        };
        if bar.message() != what {
            bar.set_message(what);
            bar.set_length(p.total);
        }
        bar.set_position(p.done);
    });
    bar.finish_and_clear();
    // Setup's scratch is freed; hand its pages back before serving.
    crate::memory::release_freed();
    Ok(pipeline?)
}

/// Which rigid moving parts a budget holds whole (`--movers-whole`;
/// [`psao_scene::MoversWhole`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MoversWholeArg {
    /// None.
    Off,
    /// Every one.
    On,
    /// Those whose own AO changes as they move, not turning in place.
    Auto,
}

impl From<MoversWholeArg> for psao_scene::MoversWhole {
    fn from(a: MoversWholeArg) -> Self {
        match a {
            MoversWholeArg::Off => psao_scene::MoversWhole::Off,
            MoversWholeArg::On => psao_scene::MoversWhole::On,
            MoversWholeArg::Auto => psao_scene::MoversWhole::Auto,
        }
    }
}

/// The scenes the `psao` binary carries (`bench --scenes`, `serve
/// --scene`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Embedded {
    /// The codec demo's scene: floor, trellis, a sliding box, a walker.
    Default,
    /// CesiumMan walking on a floor.
    CesiumMan,
    /// The procedural hall (`psao_scene::hall_scene`).
    Hall,
}

impl Embedded {
    /// Its name on the command line and in `WELCOME`.
    pub fn name(self) -> &'static str {
        match self {
            Embedded::Default => "default",
            Embedded::CesiumMan => "cesium-man",
            Embedded::Hall => "hall",
        }
    }

    /// The scene.
    pub fn scene(self) -> Scene {
        match self {
            Embedded::Default => default_scene(),
            Embedded::CesiumMan => psao_scene::cesium_man_scene(),
            Embedded::Hall => psao_scene::hall_scene(),
        }
    }
}

/// The scene at `path` (a .gltf, .glb or .obj file), an embedded scene
/// named `default`, `hall` or `cesium-man` (where no file has that name),
/// or the embedded default scene, with the name `WELCOME` gives it.
pub fn load_scene(path: Option<&Path>) -> anyhow::Result<(Scene, String)> {
    use clap::ValueEnum as _;
    let embedded = path
        .filter(|p| !p.exists())
        .and_then(|p| p.to_str())
        .and_then(|name| Embedded::from_str(name, false).ok());
    if let Some(e) = embedded {
        return Ok((e.scene(), e.name().into()));
    }
    match path {
        None => Ok((default_scene(), "default".into())),
        Some(p) => {
            let scene = load_scene_file(p)?;
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            Ok((scene, name))
        }
    }
}

/// The certificates in a PEM file.
pub fn read_roots(path: &Path) -> anyhow::Result<Vec<rustls::pki_types::CertificateDer<'static>>> {
    use rustls::pki_types::pem::PemObject;
    rustls::pki_types::CertificateDer::pem_file_iter(path)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .with_context(|| path.display().to_string())
}

/// One status line: server rate, bit rate per client, work per frame.
pub fn status(s: &ServerStats, prev: &ServerStats, dt: f64) -> String {
    let frames = (s.frames - prev.frames).max(1) as f64;
    let clients = s.clients.max(1) as f64;
    // With no client there is no ACK to age frames by.
    let age = if s.clients == 0 {
        "    -".to_string()
    } else {
        format!("{:5.1}", s.frame_age * 1e3)
    };
    format!(
        "{:5.1} fps | {:6.3} Mbit/s per client | traced {:5.0}/frame | sent {:4.0}/frame | waiting {:5} (worst {:2} frames of {:2}) | step {:5.2} ms | frame age {age} ms | {} clients",
        (s.frames - prev.frames) as f64 / dt,
        (s.written_bytes - prev.written_bytes) as f64 * 8.0 / dt / 1e6 / clients,
        (s.report.traced - prev.report.traced) as f64 / frames,
        (s.report.updated - prev.report.updated) as f64 / frames,
        s.report.waiting,
        s.report.oldest_wait,
        s.report.wait_bound,
        (s.step_time - prev.step_time).as_secs_f64() * 1e3 / frames,
        s.clients,
    )
}

/// `bytes` in B, kB, MB or GB (powers of 1000), three significant digits.
pub fn human_bytes(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        0..1_000 => format!("{bytes} B"),
        1_000..1_000_000 => format!("{:.1} kB", b / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} MB", b / 1e6),
        _ => format!("{:.2} GB", b / 1e9),
    }
}

/// CPU seconds this process has used (user + system), where /proc tells.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces), from field 3.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// What a recording wrote, in a line.
pub fn recorded(
    frames: u64,
    bytes: u64,
    dropped: u64,
    start: std::time::Instant,
    out: &Path,
) -> String {
    format!(
        "recorded {frames} frames ({bytes} bytes) in {:.1} s to {}{}",
        start.elapsed().as_secs_f64(),
        out.display(),
        if dropped > 0 {
            format!("; {dropped} frames dropped (the writer fell behind)")
        } else {
            String::new()
        }
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Affine3A, Vec3};
    use psao_scene::Mesh;

    #[test]
    fn the_lead_is_a_period_or_the_milliseconds_given() {
        assert_eq!(parse_lead("auto"), Ok(Lead::Auto));
        assert_eq!(parse_lead("25"), Ok(Lead::Millis(25.0)));
        assert_eq!(parse_lead("0"), Ok(Lead::Millis(0.0)));
        for bad in ["-1", "nan", "inf", "10001", "soon"] {
            assert!(parse_lead(bad).is_err(), "{bad}");
        }
        let args = |lead_ms| LeadArgs {
            lead_ms,
            settle_steps: 2,
        };
        let mut c = PipelineConfig::default();
        args(Lead::Auto).apply(&mut c, 50);
        assert_eq!((c.lead, c.settle_steps), (0.02, 2));
        args(Lead::Millis(5.0)).apply(&mut c, 50);
        assert_eq!(c.lead, 0.005);
    }

    fn cube(side: f32) -> Scene {
        let mut s = Scene::default();
        s.add(
            Mesh::cuboid(Vec3::ZERO, Vec3::splat(side)),
            Affine3A::IDENTITY,
        );
        s
    }

    #[test]
    fn embedded_scenes_are_named_and_files_come_first() {
        let (hall, name) = load_scene(Some(Path::new("hall"))).unwrap();
        assert_eq!(name, "hall");
        assert_eq!(
            hall.instances.len(),
            psao_scene::hall_scene().instances.len()
        );
        let (_, name) = load_scene(None).unwrap();
        assert_eq!(name, "default");
        for e in [Embedded::Default, Embedded::CesiumMan, Embedded::Hall] {
            let (scene, name) = load_scene(Some(Path::new(e.name()))).unwrap();
            assert_eq!(name, e.name());
            assert_eq!(scene.instances.len(), e.scene().instances.len());
        }
        let e = load_scene(Some(Path::new("lobby"))).unwrap_err();
        assert!(
            format!("{e:#}").contains("unsupported scene format"),
            "{e:#}"
        );
        // A file named like an embedded scene is read as a file.
        let dir = std::env::temp_dir().join(format!("psao-embedded-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("hall");
        std::fs::write(&file, b"not a scene").unwrap();
        assert!(load_scene(Some(&file)).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn scale_warnings_name_the_size_and_the_option() {
        // A 2 m cube at the defaults: nothing to say.
        assert!(scale_warnings(&cube(2.0), 1024.0, 0.6).unwrap().is_empty());
        // A 7 cm model at the paper's radius.
        let w = scale_warnings(&cube(0.07), 1024.0, 0.6).unwrap();
        assert!(
            w.len() == 1 && w[0].contains("more than half") && w[0].contains("--radius 0.007"),
            "{w:?}"
        );
        // A room in centimetres read as metres: 6 faces of 555 x 555.
        let w = scale_warnings(&cube(555.0), 16.0, 0.6).unwrap();
        assert!(
            w.len() == 1 && w[0].contains("29.6 million points") && w[0].contains("--density"),
            "{w:?}"
        );
        // A radius lost in a city.
        let w = scale_warnings(&cube(10_000.0), 1e-6, 0.6).unwrap();
        assert!(w.len() == 1 && w[0].contains("1/10,000"), "{w:?}");
    }

    /// What `BudgetArgs` sets of the pipeline's config for `args`.
    fn budget_config(args: &[&str]) -> Result<PipelineConfig, clap::Error> {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            budget: BudgetArgs,
        }
        let cli = <Cli as clap::Parser>::try_parse_from(
            std::iter::once("serve").chain(args.iter().copied()),
        )?;
        let mut config = PipelineConfig::default();
        cli.budget.apply(&mut config);
        Ok(config)
    }

    #[test]
    fn early_decisions_are_made_under_a_budget_unless_turned_off() {
        let early = |args: &[&str]| budget_config(args).unwrap().early;
        // The default budget (auto), and a fixed one: early decisions.
        assert_eq!(early(&[]), Some(psao_scene::EarlyDecisions::default()));
        assert!(early(&["--ray-budget", "20000"]).is_some());
        // The baseline traces every point in full, unless asked.
        assert_eq!(early(&["--ray-budget", "none"]), None);
        assert!(early(&["--ray-budget", "none", "--early-decisions"]).is_some());
        assert_eq!(early(&["--no-early-decisions"]), None);
        assert!(budget_config(&["--early-decisions", "--no-early-decisions"]).is_err());
    }

    /// Which servers make early decisions: by default a budgeted one, not
    /// the unbudgeted baseline, nor a "budgeted" one under `--ray-budget
    /// none`; every server with `--early-decisions`, none with
    /// `--no-early-decisions`.
    #[test]
    fn early_servers_follow_the_flags_and_the_budget() {
        let budgets = [
            RayBudget::Unlimited,
            RayBudget::Rays(20_000),
            RayBudget::Auto { share: 0.8 },
        ];
        let made = |e: EarlyServers| budgets.map(|b| e.make_them(b));
        assert_eq!(made(EarlyServers::Budgeted), [false, true, true]);
        assert_eq!(made(EarlyServers::All), [true; 3]);
        assert_eq!(made(EarlyServers::None), [false; 3]);
        assert_eq!(
            EarlyServers::from_flags(false, false),
            EarlyServers::Budgeted
        );
        assert_eq!(EarlyServers::from_flags(true, false), EarlyServers::All);
        assert_eq!(EarlyServers::from_flags(false, true), EarlyServers::None);
    }

    #[test]
    fn ray_budgets_parse_with_a_share_or_say_what_they_expect() {
        assert_eq!(parse_ray_budget("auto"), Ok(RayBudget::Auto { share: 0.8 }));
        assert_eq!(
            parse_ray_budget("auto:0.7"),
            Ok(RayBudget::Auto { share: 0.7 })
        );
        assert_eq!(parse_ray_budget("none"), Ok(RayBudget::Unlimited));
        assert_eq!(parse_ray_budget("5000"), Ok(RayBudget::Rays(5000)));
        for bad in ["auto:0", "auto:1.5", "auto:x", "auto:", "lots"] {
            let e = parse_ray_budget(bad).unwrap_err();
            assert!(e.contains(bad), "{e}");
        }
    }
}
