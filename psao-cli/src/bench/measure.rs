//! The measurements of `psao bench` for one scene.
//!
//! Frames: `frames` client frames spread evenly over the scene's camera
//! path, each at a time on the client's 60 Hz grid. For each frame the
//! scene is posed, a G-buffer is cast, and the reference is ray-traced per
//! pixel with `reference_rays` rays (closest hit, radius 0.6, the server's
//! estimator). Every method then makes an AO image on the same G-buffer:
//! - PSAO-N at rate R: a server pipeline keeping N points per square
//!   metre (the paper's N; the pipeline spawns 2N and keeps half) ticks at
//!   R Hz; at a client frame at time t the client holds the frames of every
//!   tick up to `floor((t - 1/R - network) R) / R` and reconstructs with the
//!   last transforms it received (so lower rates are staler, as in the
//!   paper's latency video); the server poses its scene that far ahead of
//!   each tick (one period plus the network's delay: the pipeline's
//!   `lead`), so what the client holds is the pose it draws, unless
//!   `lead` is off;
//! - RTAO-k: k closest-hit rays per pixel (another seed than the
//!   reference's);
//! - SAO: the screen-space baseline on the G-buffer's depth.
//!
//! Client time is the AO work per 60 Hz client frame (the G-buffer is
//! shared by all), on every core of this machine (rayon), for every method
//! alike: for PSAO the reconstruction plus decoding the frames that arrive
//! per client frame; for RTAO the rays (the per-frame BVH build a moving
//! scene needs is reported beside it); for SAO the whole pass. Each
//! method's image is made [`TIMED_RUNS`] times back to back and the median
//! counts, as a client drawing frame after frame holds its own data in
//! cache (PSAO's first run comes right after the server's ticks in this
//! same process, which a client on its own machine does not share). A server
//! tick's frame reaches the client one server period after its scene time
//! (the server computes it meanwhile) plus `network_ms`. Server time and
//! bit rate come from a window of consecutive ticks at the server rate
//! after the measured frames.

use std::time::Instant;

use anyhow::Context as _;
use indicatif::ProgressBar;
use psao_codec::{Decoder, Limits};
use psao_eval::{
    NO_INSTANCE, PosedScene, SaoParams, View, psao_image, psao_image_seen, ray_traced_ao, rmse,
    sao, ssim,
};
use psao_scene::{
    AoBackend, AoParams, Camera, Estimator, Pipeline, PipelineConfig, RayBudget, Scene,
    SetupProgress, SetupStage,
};

use super::Backend;
use super::images;
use super::model::{Breakdown, Frame, Method, Row, SceneResult, Showcase, Shown};
use crate::cmd::common::EarlyServers;

/// Ticks an unbudgeted server steps one by one before each measured
/// frame (the rest of the way there in one step).
pub const WARM_TICKS: u64 = 4;

/// Times each method's image is made per measured frame, back to back;
/// its client time is the median.
pub const TIMED_RUNS: usize = 3;

/// Runs `f` [`TIMED_RUNS`] times; the last result, and the median of the
/// runs' milliseconds.
fn timed<T>(mut f: impl FnMut() -> anyhow::Result<T>) -> anyhow::Result<(T, f64)> {
    let mut ms = Vec::with_capacity(TIMED_RUNS);
    let mut last = None;
    for _ in 0..TIMED_RUNS {
        let t = Instant::now();
        last = Some(f()?);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    let out = last.context("no timed run")?;
    Ok((out, ms[ms.len() / 2]))
}

/// Client frames per second: frame times lie on this grid.
pub const CLIENT_HZ: f64 = 60.0;

/// Most pixels in one image (3840 x 2160); all frames together may hold
/// 8 times this (the bench keeps every frame's G-buffer and reference).
pub const MAX_PIXELS: u64 = 3840 * 2160;

/// What to measure.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Frames of the camera path.
    pub frames: u32,
    /// Rays per pixel of the reference.
    pub reference_rays: u32,
    /// AO rays per PSAO point.
    pub point_rays: u32,
    /// PSAO densities N (points kept per unit area, the paper's N).
    pub densities: Vec<f32>,
    /// Server rates, Hz.
    pub rates: Vec<u16>,
    /// Every density at every rate (else every density at the first rate,
    /// and every rate at [`focus`](Self::focus)).
    pub cross: bool,
    /// The density the rate sweep uses (when not `cross`) and the one the
    /// side-by-side image shows.
    pub focus: f32,
    /// Rays per pixel of the RTAO configurations.
    pub rtao_rays: Vec<u32>,
    /// Seconds of consecutive ticks for server time and bit rate.
    pub window: f32,
    /// Network delay, ms: a tick's frame reaches the client one server
    /// period plus this after its scene time.
    pub network_ms: f32,
    /// Where PSAO servers trace.
    pub backend: Backend,
    /// AO radius R in scene units (the reference, PSAO, RTAO and SAO).
    pub radius: f32,
    /// Buried points take their visible neighbours' AO (else they are
    /// traced: the baseline).
    pub fill_buried: bool,
    /// Deforming instances keep their points in bind space (point format
    /// 1; else posed, format 0: the baseline).
    pub bind_space: bool,
    /// Full cells continue in overflow chains (spec/wire-format.md 7.4;
    /// else their extra points are dropped: the baseline).
    pub overflow: bool,
    /// Gaps that sample elimination leaves on thin strips are filled, and
    /// small meshes spawn a few points (else elimination's points alone:
    /// the baseline).
    pub fill_gaps: bool,
    /// PSAO servers pose the scene one period plus `network_ms` ahead of
    /// each tick, the time its frame is shown
    /// ([`PipelineConfig::lead`](psao_scene::PipelineConfig::lead)), or at
    /// the tick itself (false: the baseline, a period or more behind).
    pub lead: bool,
    /// PSAO servers' [`PipelineConfig::settle_steps`](psao_scene::PipelineConfig::settle_steps)
    /// (0: points stay within the send threshold where motion passed and
    /// left AO short of open, the baseline).
    pub settle_steps: u8,
    /// A ray budget for the servers of extra PSAO configurations, one per
    /// density at the first rate ("PSAO-N @R Hz budget"), beside the
    /// unbudgeted ones (`None`: none). With one, every PSAO server steps
    /// tick by tick to each measured frame (a budget is per tick), not in
    /// one step.
    pub budget: Option<RayBudget>,
    /// Under the budget, the most steps a point waits while the budget
    /// affords it.
    pub max_wait: u32,
    /// Under the budget, the most steps the bound on waiting rises to
    /// with demand (at least `max_wait`).
    pub max_wait_limit: u32,
    /// Under the budget, movers' own points are traced every step
    /// ([`PipelineConfig::movers_every_step`](psao_scene::PipelineConfig::movers_every_step)).
    pub movers_every_step: bool,
    /// Under the budget, rigid movers are traced whole, their transform
    /// held back while they wait
    /// ([`PipelineConfig::movers_whole`](psao_scene::PipelineConfig::movers_whole)).
    pub movers_whole: psao_scene::MoversWhole,
    /// Under the budget, points that wait long are planned late
    /// ([`PipelineConfig::plan_late`](psao_scene::PipelineConfig::plan_late)).
    pub plan_late: bool,
    /// Under the budget, the loop memory's cap in bytes
    /// ([`PipelineConfig::loop_memory_bytes`](psao_scene::PipelineConfig::loop_memory_bytes)).
    pub loop_memory_bytes: u64,
    /// Under the budget, the loop memory verifies waiting points
    /// ([`PipelineConfig::loop_verify`](psao_scene::PipelineConfig::loop_verify)).
    pub loop_verify: bool,
    /// Which PSAO servers make early decisions
    /// ([`PipelineConfig::early`](psao_scene::PipelineConfig::early), the
    /// defaults).
    pub early: EarlyServers,
    /// PSAO servers keep the scores of the rays motion did not reach and
    /// re-trace only the reached ones (on the CPU backend, and on the GPU
    /// backend with [`gpu_single_rays`](Self::gpu_single_rays))
    /// ([`PipelineConfig::ray_reuse`](psao_scene::PipelineConfig::ray_reuse)),
    /// or (false: the baseline) every ray of a point they trace.
    pub ray_reuse: bool,
    /// PSAO servers on the CPU backend know a point open without a ray
    /// where no triangle lies within reach of its rays
    /// ([`PipelineConfig::skip_open`](psao_scene::PipelineConfig::skip_open)),
    /// or (false: the baseline) trace it.
    pub skip_open: bool,
    /// On the GPU backend, PSAO servers cast single rays (psao-gpu's
    /// `GpuBackend::with_single_rays`): ray scores kept as on the CPU,
    /// with ray reuse and early decisions; or (false, the default) trace
    /// whole points.
    pub gpu_single_rays: bool,
    /// The PSAO client also leaves out candidate points its view shows
    /// hidden behind another surface that faces the pixel
    /// (spec/wire-format.md 7.3.1, [`psao_eval::psao_image_seen`]; true,
    /// the default), or weighs every candidate by eq. 2-3 alone.
    pub hidden_test: bool,
    /// Which measured frames are saved as images.
    pub image_frames: ImageFrames,
}

/// Which measured frames `psao bench` saves as images (`--image-frames`):
/// their AO of each shown method, the reference and G-buffer as EXR, and
/// the side-by-side picture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ImageFrames {
    /// Every measured frame.
    All,
    /// These frames (0-based indices into the measured frames, ascending,
    /// no repeats).
    List(Vec<usize>),
}

impl ImageFrames {
    /// Parses `--image-frames`: `all`, or a comma-separated list of 0-based
    /// frame indices (sorted and deduplicated here). The error says which
    /// part is not an index.
    pub fn parse(text: &str) -> Result<ImageFrames, String> {
        let text = text.trim();
        if text.eq_ignore_ascii_case("all") {
            return Ok(ImageFrames::All);
        }
        let mut list = Vec::new();
        for part in text.split(',') {
            let part = part.trim();
            if part.is_empty() {
                return Err(format!(
                    "`{text}` has an empty entry, which is not a frame index: give 0-based indices separated by commas (as in 0,2,5), or `all`"
                ));
            }
            let k = part.parse::<usize>().map_err(|_| {
                format!(
                    "`{part}` is not a frame index: give 0-based indices of the measured frames separated by commas (as in 0,2,5), or `all`"
                )
            })?;
            list.push(k);
        }
        list.sort_unstable();
        list.dedup();
        Ok(ImageFrames::List(list))
    }

    /// The indices to save when `measured` frames were measured, ascending
    /// (those of a list that are in range).
    pub fn indices(&self, measured: usize) -> Vec<usize> {
        match self {
            ImageFrames::All => (0..measured).collect(),
            ImageFrames::List(list) => list.iter().copied().filter(|&k| k < measured).collect(),
        }
    }

    /// The first listed index that is not below `measured`, if any.
    pub fn out_of_range(&self, measured: usize) -> Option<usize> {
        match self {
            ImageFrames::All => None,
            ImageFrames::List(list) => list.iter().copied().find(|&k| k >= measured),
        }
    }
}

impl std::fmt::Display for ImageFrames {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageFrames::All => f.write_str("all"),
            ImageFrames::List(list) => {
                let parts: Vec<String> = list.iter().map(|k| k.to_string()).collect();
                f.write_str(&parts.join(","))
            }
        }
    }
}

impl Settings {
    /// Defaults that finish in a few minutes on 2 cores.
    pub fn quick() -> Settings {
        Settings {
            width: 320,
            height: 180,
            frames: 6,
            reference_rays: 256,
            point_rays: 64,
            densities: vec![128.0, 256.0, 512.0, 1024.0, 2048.0],
            rates: vec![60, 30, 15, 5],
            cross: false,
            focus: 1024.0,
            rtao_rays: vec![1, 4, 16],
            window: 1.0,
            network_ms: 0.0,
            backend: Backend::Cpu,
            radius: AoParams::default().radius,
            fill_buried: true,
            bind_space: true,
            overflow: true,
            fill_gaps: true,
            lead: true,
            settle_steps: PipelineConfig::default().settle_steps,
            budget: None,
            max_wait: 8,
            max_wait_limit: PipelineConfig::default().max_wait_limit,
            movers_every_step: false,
            movers_whole: psao_scene::MoversWhole::Auto,
            plan_late: false,
            loop_memory_bytes: PipelineConfig::default().loop_memory_bytes,
            loop_verify: true,
            early: EarlyServers::Budgeted,
            ray_reuse: true,
            skip_open: true,
            gpu_single_rays: false,
            hidden_test: true,
            image_frames: ImageFrames::List(vec![0]),
        }
    }

    /// The paper-sized run.
    pub fn full() -> Settings {
        Settings {
            width: 1280,
            height: 720,
            frames: 24,
            reference_rays: 512,
            point_rays: 192,
            cross: true,
            window: 2.0,
            ..Settings::quick()
        }
    }

    /// Checks the settings make sense.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.frames == 0 {
            anyhow::bail!("--frames must be at least 1");
        }
        if let Some(k) = self.image_frames.out_of_range(self.frames as usize) {
            anyhow::bail!(
                "--image-frames {k} is out of range: --frames {} measures frames 0 to {} (indices are 0-based)",
                self.frames,
                self.frames - 1
            );
        }
        if self.image_frames == ImageFrames::List(Vec::new()) {
            anyhow::bail!("--image-frames needs at least one frame index (or `all`)");
        }
        if self.reference_rays == 0 || self.point_rays == 0 {
            anyhow::bail!("--reference-rays and --point-rays must be at least 1");
        }
        if self.densities.is_empty() || self.rates.is_empty() {
            anyhow::bail!("--densities and --rates need at least one value");
        }
        if let Some(d) = self
            .densities
            .iter()
            .find(|d| !(d.is_finite() && **d > 0.0))
        {
            anyhow::bail!("density {d} is not a positive number");
        }
        if self.rates.contains(&0) {
            anyhow::bail!("a server rate of 0 Hz never ticks");
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            anyhow::bail!("--radius {} is not a positive number", self.radius);
        }
        if self.gpu_single_rays && self.backend != Backend::Gpu {
            anyhow::bail!("--gpu-single-rays needs --backend gpu");
        }
        if self.backend == Backend::Gpu && !cfg!(feature = "gpu") {
            anyhow::bail!(
                "this psao was built without GPU support: cargo run --release -p psao-cli --features gpu --bin psao -- bench --backend gpu"
            );
        }
        if !(self.network_ms.is_finite() && (0.0..=10_000.0).contains(&self.network_ms)) {
            anyhow::bail!("--network-ms must lie in [0, 10000]");
        }
        let pixels = self.width as u64 * self.height as u64;
        if pixels == 0 || pixels > MAX_PIXELS {
            anyhow::bail!(
                "{}x{} is {pixels} pixels; the bench takes 1 to {MAX_PIXELS}",
                self.width,
                self.height
            );
        }
        if pixels * self.frames as u64 > MAX_PIXELS * 8 {
            anyhow::bail!(
                "{} frames of {pixels} pixels is more than the bench holds ({} pixels in all)",
                self.frames,
                MAX_PIXELS * 8
            );
        }
        Ok(())
    }

    /// The density shown in the side-by-side image and used by the rate
    /// sweep: the configured focus if listed, else the listed density
    /// nearest to it.
    pub fn focus_density(&self) -> f32 {
        self.densities
            .iter()
            .copied()
            .min_by(|a, b| (a - self.focus).abs().total_cmp(&(b - self.focus).abs()))
            .unwrap_or(self.focus)
    }

    /// The PSAO configurations, (density, rate), in table order (densities
    /// ascending).
    pub fn psao_configs(&self) -> Vec<(f32, u16)> {
        let mut densities = self.densities.clone();
        densities.sort_by(f32::total_cmp);
        densities.dedup();
        let mut out = Vec::new();
        if self.cross {
            for &r in &self.rates {
                for &d in &densities {
                    out.push((d, r));
                }
            }
        } else {
            let first = self.rates[0];
            out.extend(densities.iter().map(|&d| (d, first)));
            let f = self.focus_density();
            out.extend(self.rates[1..].iter().map(|&r| (f, r)));
        }
        out
    }

    /// The budgeted PSAO configurations, (density, rate): every density
    /// at the first rate, when a budget is set.
    pub fn budget_configs(&self) -> Vec<(f32, u16)> {
        if self.budget.is_none() {
            return Vec::new();
        }
        let mut densities = self.densities.clone();
        densities.sort_by(f32::total_cmp);
        densities.dedup();
        densities.iter().map(|&d| (d, self.rates[0])).collect()
    }

    /// Progress units per scene: the reference, each PSAO configuration,
    /// each RTAO configuration and SAO.
    pub fn units_per_scene(&self) -> u64 {
        1 + self.psao_configs().len() as u64
            + self.budget_configs().len() as u64
            + self.rtao_rays.len() as u64
            + 1
    }
}

/// Running means of the error metrics over frames.
#[derive(Default)]
struct Errors {
    mse: f64,
    ssim: f64,
    flip: f64,
    frames: u32,
    /// Squared error per instance id.
    sse_by_instance: std::collections::BTreeMap<u32, f64>,
    /// Squared error in pixels left open where the reference is dark.
    sse_open_where_dark: f64,
    /// Squared error, and pixels, made dark where the reference is open.
    sse_dark_where_open: f64,
    dark_where_open_px: u64,
    covered: u64,
    sse: f64,
}

impl Errors {
    fn add(&mut self, frame: &Frame, test: &[f32]) -> anyhow::Result<()> {
        let e = rmse(&frame.reference, test)?;
        self.mse += e * e;
        self.ssim += ssim(
            &frame.reference,
            test,
            frame.gbuffer.width as usize,
            frame.gbuffer.height as usize,
        )?;
        self.flip += images::flip_mean(frame, test);
        self.frames += 1;
        let g = &frame.gbuffer;
        for ((&id, &r), &t) in g.instance.iter().zip(&frame.reference).zip(test) {
            if id == NO_INSTANCE {
                continue;
            }
            let e = ((t - r) as f64).powi(2);
            self.sse += e;
            *self.sse_by_instance.entry(id).or_default() += e;
            if t >= psao_eval::SHOWN_OPEN && r < psao_eval::REFERENCE_DARK {
                self.sse_open_where_dark += e;
            }
            if r > super::model::OPEN && t < r - super::model::DARKER {
                self.sse_dark_where_open += e;
                self.dark_where_open_px += 1;
            }
            self.covered += 1;
        }
        Ok(())
    }

    fn breakdown(&self) -> Breakdown {
        let total = self.sse.max(f64::MIN_POSITIVE);
        let mut by_instance: Vec<(u32, f64)> = self
            .sse_by_instance
            .iter()
            .map(|(&id, &e)| (id, e / total))
            .collect();
        by_instance.sort_by(|a, b| b.1.total_cmp(&a.1));
        Breakdown {
            by_instance,
            open_where_dark: self.sse_open_where_dark / total,
            dark_where_open: self.sse_dark_where_open / total,
            dark_where_open_px: self.dark_where_open_px as f64 / self.covered.max(1) as f64,
            open_causes: Vec::new(),
        }
    }

    fn row(&self, method: Method, client_ms: f64) -> Row {
        let n = self.frames.max(1) as f64;
        let mse = self.mse / n;
        Row {
            method,
            server_ms: None,
            client_ms,
            mbit_s: None,
            rmse: mse.sqrt(),
            psnr: if mse > 0.0 {
                10.0 * (1.0 / mse).log10()
            } else {
                f64::INFINITY
            },
            ssim: self.ssim / n,
            flip: self.flip / n,
            points: None,
            setup_s: None,
            keyframe_bytes: None,
            dropped: None,
            unknown_px: 0,
            extra_ms: None,
            breakdown: self.breakdown(),
            worst_wait: None,
            rays_per_tick: None,
            ticks_over: None,
        }
    }
}

/// Client frames in one tick of the slowest default server rate (5 Hz).
const PHASES: u64 = 12;

/// Times of the measured frames: spread evenly over the camera path (a
/// frame near each of `frames` equal parts' middles), on the 60 Hz grid.
/// Frame `k` is moved on by `7k mod 12` client frames, so the frames fall
/// at every phase of a 5, 15 or 30 Hz server tick rather than all on a
/// tick (which would hide the staleness of slow servers).
pub fn frame_times(duration: f32, frames: u32) -> Vec<f32> {
    let mut times = (0..frames)
        .map(|k| {
            let t = (k as f64 + 0.5) / frames as f64 * duration.max(0.0) as f64;
            let phase = (7 * k as u64 % PHASES) as f64;
            (((t * CLIENT_HZ).round() + phase) / CLIENT_HZ) as f32
        })
        .collect::<Vec<f32>>();
    // Frames closer than the phase shift could otherwise swap order.
    times.sort_by(f32::total_cmp);
    times.dedup();
    times
}

/// The reference's AO parameters (closest hit, the server's radius and
/// bias).
fn reference_params(rays: u32, seed: u64, radius: f32) -> AoParams {
    AoParams {
        rays,
        estimator: Estimator::ClosestHit,
        seed,
        radius,
        ..AoParams::default()
    }
}

/// How many frames the bench measures on a path of `duration` seconds
/// (frame times that coincide on the 60 Hz grid count once).
pub fn measured_frames(duration: f32, frames: u32) -> usize {
    frame_times(duration, frames).len()
}

/// The progress message of a pipeline's setup: the stage and how far it
/// is, in percent ("setup: tracing 41%").
pub fn setup_message(p: SetupProgress) -> String {
    let stage = match p.stage {
        SetupStage::Points => "points and grids",
        SetupStage::Buried => "buried points",
        SetupStage::Trace => "tracing",
        _ => "preparing",
    };
    let percent = (p.done.min(p.total) * 100)
        .checked_div(p.total)
        .unwrap_or(100);
    format!("setup: {stage} {percent}%")
}

/// Measures every configuration on one scene. The bar's message says what
/// runs: the configuration, the pipeline's setup stage and the frame.
pub fn measure_scene(
    name: &str,
    scene: Scene,
    s: &Settings,
    bar: &ProgressBar,
) -> anyhow::Result<SceneResult> {
    let err = |e: psao_scene::SceneError| anyhow::Error::from(e).context(name.to_string());
    let path = scene
        .camera
        .clone()
        .with_context(|| format!("{name}: the scene has no camera path"))?;
    let times = frame_times(path.duration(), s.frames);
    if let Some(k) = s.image_frames.out_of_range(times.len()) {
        anyhow::bail!(
            "{name}: --image-frames {k} is out of range: its camera path gives {} distinct frames",
            times.len()
        );
    }
    let started = Instant::now();
    let mut frames = Vec::new();
    let mut covered = 0usize;
    let n = times.len();
    for (k, &t) in times.iter().enumerate() {
        bar.set_message(format!("{name}: reference: frame {}/{n}", k + 1));
        let camera: Camera = path.at(t);
        let view = View::new(camera, s.width, s.height).map_err(err)?;
        let t0 = Instant::now();
        let posed = PosedScene::new(&scene, t).map_err(err)?;
        let bvh_ms = t0.elapsed().as_secs_f64() * 1e3;
        let gbuffer = posed.gbuffer(&view);
        covered += gbuffer.covered();
        let reference = ray_traced_ao(
            &posed.tracer(),
            &gbuffer,
            &reference_params(s.reference_rays, 0x5EED_0001, s.radius),
        )
        .map_err(err)?;
        let composite = images::composite(&gbuffer, &reference);
        frames.push(Frame {
            time: t,
            view,
            gbuffer,
            reference,
            composite,
            posed,
            bvh_ms,
        });
    }
    let reference_s = started.elapsed().as_secs_f64();
    let pixels = frames.len() * (s.width as usize * s.height as usize);
    if covered == 0 {
        anyhow::bail!(
            "{name}: the camera sees none of the scene in any of the {} frames (check --camera or --camera-path)",
            frames.len()
        );
    }
    if covered * 2 < pixels {
        bar.println(format!(
            "warning: {name}: the camera sees the scene in {:.0}% of pixels (below 50%: the errors measure little of it)",
            covered as f64 * 100.0 / pixels as f64
        ));
    }
    bar.inc(1);
    let mut rows = Vec::new();
    // Only the frames asked for keep their images.
    let keep = s.image_frames.indices(frames.len());
    let mut showcase = Showcase {
        frames: keep
            .iter()
            .map(|&frame| Shown {
                frame,
                images: Vec::new(),
                open_causes: Vec::new(),
            })
            .collect(),
    };

    let focus = s.focus_density();
    let first_rate = s.rates[0];
    let configs = s.psao_configs().into_iter().map(|c| (c, false));
    for ((density, rate), budget) in
        configs.chain(s.budget_configs().into_iter().map(|c| (c, true)))
    {
        let method = Method::Psao {
            density,
            rate,
            budget,
        };
        let label = method.label();
        bar.set_message(format!("{name}: {label}"));
        let say = |what: &str| bar.set_message(format!("{name}: {label}: {what}"));
        // The focus density's images at the first rate, with and without
        // a budget (the open causes are the unbudgeted server's).
        let shown = density == focus && rate == first_rate;
        let (row, kept) = measure_psao(
            &scene,
            &frames,
            s,
            (density, rate, budget),
            if shown { &keep } else { &[] },
            &say,
        )
        .with_context(|| format!("{name}: {label}"))?;
        for (k, img, causes) in kept {
            let causes = if budget { Vec::new() } else { causes };
            showcase.add_with_causes(k, label.clone(), img, causes);
        }
        rows.push(row);
        bar.inc(1);
    }
    for &rays in &s.rtao_rays {
        let method = Method::Rtao { rays };
        let label = method.label();
        let (mut errors, mut ms) = (Errors::default(), 0.0);
        for (k, f) in frames.iter().enumerate() {
            bar.set_message(format!("{name}: {label}: frame {}/{n}", k + 1));
            let tracer = f.posed.tracer();
            let (img, t) = timed(|| {
                ray_traced_ao(
                    &tracer,
                    &f.gbuffer,
                    &reference_params(rays, 0xA0_0002, s.radius),
                )
                .map_err(err)
            })?;
            ms += t;
            errors.add(f, &img)?;
            if rays == s.rtao_rays[0] && keep.contains(&k) {
                showcase.add(k, label.clone(), img);
            }
        }
        let mut row = errors.row(method, ms / frames.len() as f64);
        row.extra_ms = Some(frames.iter().map(|f| f.bvh_ms).sum::<f64>() / frames.len() as f64);
        rows.push(row);
        bar.inc(1);
    }
    let (mut errors, mut ms) = (Errors::default(), 0.0);
    let params = SaoParams {
        radius: s.radius,
        ..SaoParams::default()
    };
    for (k, f) in frames.iter().enumerate() {
        bar.set_message(format!("{name}: SAO: frame {}/{n}", k + 1));
        let (img, t) = timed(|| sao(&f.gbuffer.depth, &f.view, &params).map_err(err))?;
        ms += t;
        errors.add(f, &img)?;
        if keep.contains(&k) {
            showcase.add(k, "SAO".into(), img);
        }
    }
    rows.push(errors.row(Method::Sao, ms / frames.len() as f64));
    bar.inc(1);
    let dynamic = scene.dynamic_instances();
    let kinds = scene
        .instances
        .iter()
        .enumerate()
        .map(|(i, inst)| {
            let motion = if inst.skin.is_some() {
                "skinned"
            } else if dynamic[i] {
                "moving"
            } else {
                "static"
            };
            let alpha = scene.meshes[inst.mesh].alpha.is_some();
            format!("{motion}{}", if alpha { ", alpha-masked" } else { "" })
        })
        .collect();
    Ok(SceneResult {
        kinds,
        name: name.to_string(),
        rows,
        coverage: covered as f64 / pixels.max(1) as f64,
        triangles: frames[0].posed.triangles(),
        frames,
        showcase,
        reference_s,
    })
}

/// A frame's index and a method's AO image of it.
type KeptImage = (usize, Vec<f32>, Vec<u8>);

/// Measures PSAO at one (density, server rate); also returns its images
/// of the frames in `keep` (indices into `frames`), and only those.
/// `say` hears what runs: the setup's stage and progress, then the frame.
fn measure_psao(
    scene: &Scene,
    frames: &[Frame],
    s: &Settings,
    (density, rate, budget): (f32, u16, bool),
    keep: &[usize],
    say: &(dyn Fn(&str) + Sync),
) -> anyhow::Result<(Row, Vec<KeptImage>)> {
    // `density` counts points kept, as every command's --density does.
    let mut config = crate::cmd::common::pipeline_config(density, s.point_rays, s.radius);
    if budget {
        config.budget = s.budget.unwrap_or(RayBudget::Unlimited);
        config.max_wait = s.max_wait;
        config.max_wait_limit = s.max_wait_limit.max(s.max_wait);
        config.movers_every_step = s.movers_every_step;
        config.movers_whole = s.movers_whole;
        config.plan_late = s.plan_late;
        config.loop_memory_bytes = s.loop_memory_bytes;
        config.loop_verify = s.loop_verify;
    }
    config.early = s
        .early
        .make_them(config.budget)
        .then(psao_scene::EarlyDecisions::default);
    config.fill_buried = s.fill_buried;
    config.bind_space = s.bind_space;
    config.layout.overflow = s.overflow;
    config.fill_gaps = s.fill_gaps;
    let period = 1.0 / rate as f64;
    config.settle_steps = s.settle_steps;
    config.ray_reuse = s.ray_reuse;
    config.skip_open = s.skip_open;
    if s.lead {
        config.lead = (period + s.network_ms as f64 / 1e3) as f32;
    }
    let started = Instant::now();
    say("setup");
    let backend = match s.backend {
        Backend::Cpu => None,
        Backend::Gpu => Some(gpu_backend(scene, s.gpu_single_rays)?),
    };
    let mut pipeline =
        Pipeline::with_progress(scene.clone(), config, backend, &|p| say(&setup_message(p)))?;
    say("keyframe");
    let mut client = Decoder::new(Limits::default());
    let keyframe = pipeline.keyframe()?;
    client.receive(&keyframe.bytes).context("keyframe")?;
    let setup_s = started.elapsed().as_secs_f64();
    let points: usize = (0..pipeline.instance_count())
        .filter_map(|i| pipeline.points(i).map(|p| p.len()))
        .sum();
    let (mut errors, mut ms, mut unknown) = (Errors::default(), 0.0, 0usize);
    let mut open = psao_eval::OpenReasons::default();
    let mut worst_wait = 0u32;
    // Rays cast, and the ticks stepped (a step of several ticks counts
    // as many).
    let (mut rays, mut stepped) = (0u64, 0u64);
    let mut kept = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        say(&format!("frame {}/{}", k + 1, frames.len()));
        // The newest frame the client holds: a tick's frame is ready one
        // server period after its scene time (the server computes it
        // during that period), plus the network's delay.
        let ready = f.time as f64 - period - s.network_ms as f64 / 1e3;
        let tick = ((ready + 1e-6) / period).floor().max(0.0) * period;
        let dt = tick - pipeline.time() as f64;
        if dt < -1e-6 {
            anyhow::bail!(
                "frame times must not go back (tick {tick:.4} s after {:.4} s)",
                pipeline.time()
            );
        }
        if dt > 1e-6 {
            // With a budget in the run, every server steps tick by tick (a
            // budget is per tick); else in one step to WARM_TICKS ticks
            // before the frame's, then tick by tick, so that what the
            // last ticks do (the settle pass a tick after motion leaves a
            // point) is as at the rate.
            let ticks = ((dt / period).round() as u64).max(1);
            let mut steps = Vec::new();
            if s.budget.is_some() || ticks <= WARM_TICKS {
                steps.resize(ticks as usize, dt / ticks as f64);
            } else {
                steps.push(dt - WARM_TICKS as f64 * period);
                steps.resize(WARM_TICKS as usize + 1, period);
            }
            for step in steps {
                let (frame, r) = pipeline.step(step as f32)?;
                worst_wait = worst_wait.max(r.oldest_wait);
                rays += r.rays;
                stepped += ((step / period).round() as u64).max(1);
                if let Some(frame) = frame {
                    client.receive(&frame.bytes).context("frame")?;
                }
            }
        }
        let (img, t) = timed(|| {
            Ok(if s.hidden_test {
                psao_image_seen(client.mirror(), &f.gbuffer, &f.view)?
            } else {
                psao_image(client.mirror(), &f.gbuffer)?
            })
        })?;
        ms += t;
        unknown += img.unknown;
        errors.add(f, &img.ao)?;
        open.merge(&psao_eval::open_reasons(
            client.mirror(),
            &f.gbuffer,
            &f.reference,
            &img.ao,
        ));
        if keep.contains(&k) {
            let causes: Vec<u8> = (0..img.ao.len())
                .map(|p| {
                    let open = img.ao[p] >= psao_eval::SHOWN_OPEN
                        && f.reference[p] < psao_eval::REFERENCE_DARK;
                    open.then(|| psao_eval::open_cause(client.mirror(), &f.gbuffer, p))
                        .flatten()
                        .map_or(0, |c| c as u8 + 1)
                })
                .collect();
            kept.push((k, img.ao, causes));
        }
    }
    // Server time and bit rate: consecutive ticks at the server rate.
    say("server ticks");
    let ticks = ((s.window as f64 * rate as f64).round() as u32).max(1);
    let (mut bytes, mut server_s, mut decode_s) = (0usize, 0.0f64, 0.0f64);
    // Ticks longer than the period, and the longest (seconds).
    let (mut over, mut longest) = (0u32, 0.0f64);
    for _ in 0..ticks {
        let t = Instant::now();
        let (frame, r) = pipeline.step(period as f32)?;
        worst_wait = worst_wait.max(r.oldest_wait);
        rays += r.rays;
        stepped += 1;
        let took = t.elapsed().as_secs_f64();
        server_s += took;
        over += u32::from(took > period);
        longest = longest.max(took);
        if let Some(frame) = frame {
            bytes += frame.bytes.len();
            let t = Instant::now();
            client.receive(&frame.bytes).context("frame")?;
            decode_s += t.elapsed().as_secs_f64();
        }
    }
    let seconds = ticks as f64 * period;
    // Client time per 60 Hz frame: the reconstruction, plus decoding the
    // frames that arrive per client frame (rate / 60 of them).
    let decode_ms = decode_s * 1e3 / ticks as f64 * rate as f64 / CLIENT_HZ;
    let mut row = errors.row(
        Method::Psao {
            density,
            rate,
            budget,
        },
        ms / frames.len() as f64 + decode_ms,
    );
    row.extra_ms = Some(decode_ms);
    row.server_ms = Some(server_s * 1e3 / ticks as f64);
    row.mbit_s = Some(bytes as f64 * 8.0 / seconds / 1e6);
    row.points = Some(points);
    row.setup_s = Some(setup_s);
    row.keyframe_bytes = Some(keyframe.bytes.len());
    row.dropped = Some(
        (0..pipeline.instance_count())
            .filter_map(|i| pipeline.table(i))
            .map(|t| t.stats().dropped as u64)
            .sum(),
    );
    row.unknown_px = unknown;
    row.worst_wait = Some(worst_wait);
    row.rays_per_tick = Some(rays as f64 / stepped.max(1) as f64);
    row.ticks_over = Some((over, ticks, longest * 1e3));
    let total = errors.sse.max(f64::MIN_POSITIVE);
    row.breakdown.open_causes = open
        .causes()
        .into_iter()
        .map(|(name, c)| (name, c.sse / total))
        .collect();
    Ok((row, kept))
}

/// A backend tracing with wgpu ray queries.
#[cfg(feature = "gpu")]
fn gpu_backend(scene: &Scene, single_rays: bool) -> anyhow::Result<Box<dyn AoBackend>> {
    Ok(Box::new(
        psao_gpu::GpuBackend::new(scene)?.with_single_rays(single_rays),
    ))
}

/// Without the `gpu` feature there is no GPU backend (`Settings::validate`
/// says so first).
#[cfg(not(feature = "gpu"))]
fn gpu_backend(_scene: &Scene, _single_rays: bool) -> anyhow::Result<Box<dyn AoBackend>> {
    Err(anyhow::anyhow!(
        "this psao was built without GPU support (--features gpu)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_frames_parse_lists_and_all() {
        assert_eq!(ImageFrames::parse("0"), Ok(ImageFrames::List(vec![0])));
        assert_eq!(
            ImageFrames::parse("5, 0,2,2"),
            Ok(ImageFrames::List(vec![0, 2, 5]))
        );
        assert_eq!(ImageFrames::parse("ALL"), Ok(ImageFrames::All));
        for bad in ["", "1,,2", "-1", "x", "1.5", "all,1"] {
            let e = ImageFrames::parse(bad).expect_err(bad);
            assert!(e.contains("is not a frame index"), "{bad}: {e}");
        }
        assert_eq!(ImageFrames::List(vec![0, 3]).to_string(), "0,3");
    }

    #[test]
    fn image_frames_pick_only_measured_frames() {
        assert_eq!(ImageFrames::All.indices(3), vec![0, 1, 2]);
        let list = ImageFrames::List(vec![1, 4]);
        assert_eq!(list.indices(3), vec![1]);
        assert_eq!(list.out_of_range(3), Some(4));
        assert_eq!(list.out_of_range(5), None);
        assert_eq!(ImageFrames::All.out_of_range(0), None);
    }

    #[test]
    fn settings_refuse_an_image_frame_past_the_last() {
        let mut s = Settings::quick();
        s.frames = 3;
        s.image_frames = ImageFrames::List(vec![0, 3]);
        let e = s.validate().expect_err("frame 3 of 3").to_string();
        assert!(e.contains("--image-frames 3"), "{e}");
        assert!(e.contains("0 to 2"), "{e}");
        s.image_frames = ImageFrames::List(vec![2]);
        assert!(s.validate().is_ok());
        s.image_frames = ImageFrames::All;
        assert!(s.validate().is_ok());
    }

    #[test]
    fn single_rays_need_the_gpu_backend() {
        let mut s = Settings::quick();
        s.gpu_single_rays = true;
        let e = s
            .validate()
            .expect_err("single rays on the CPU")
            .to_string();
        assert!(e.contains("--gpu-single-rays needs --backend gpu"), "{e}");
        s.backend = Backend::Gpu;
        // Accepted where psao-gpu is built in.
        assert_eq!(s.validate().is_ok(), cfg!(feature = "gpu"));
    }

    #[test]
    fn setup_message_names_the_stage_and_percent() {
        let p = |stage, done, total| SetupProgress { stage, done, total };
        assert_eq!(
            setup_message(p(SetupStage::Trace, 41, 100)),
            "setup: tracing 41%"
        );
        assert_eq!(
            setup_message(p(SetupStage::Points, 1, 3)),
            "setup: points and grids 33%"
        );
        assert_eq!(
            setup_message(p(SetupStage::Trace, 0, 0)),
            "setup: tracing 100%"
        );
    }
}
