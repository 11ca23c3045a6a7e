//! The main job on the embedded default scene: a server traces AO for the
//! scene's points and streams 10 s at 60 Hz to a client in-process (real
//! frames, decoder and mirror). Prints per-stage times, points traced and
//! sent, bit rate, and checks the client's mirror against the server.
//!
//! Options:
//! - `--no-skip`: re-trace every point every frame (the baseline that
//!   skipping is measured against);
//! - `--no-split`: rebuild one BVH over everything when something moves
//!   (the baseline of the static/moving BVH split);
//! - `--no-ray-reuse`: trace every point within reach of motion in full
//!   (the baseline of re-tracing only the rays motion reaches);
//! - `--no-skip-open`: trace a point even where no triangle lies within
//!   reach of its rays (the baseline of knowing such a point open);
//! - `--ray-budget N` (rays per frame) or `--ray-budget auto` (as many as
//!   80% of the frame period affords): points past it wait, at most
//!   `--max-wait` frames (8); `--movers-every-step` traces a moving
//!   instance's own points every frame whatever the budget;
//!   `--movers-whole off|on|auto` holds none, every, or the pose-dependent
//!   rigid moving parts whole (`PipelineConfig::movers_whole`; `auto`
//!   by default, `on` for `--movers-whole` alone);
//!   `--plan-late` plans points that wait long once, when the budget
//!   takes them (`PipelineConfig::plan_late`); `--loop-memory-mib M`
//!   caps the loop memory (`PipelineConfig::loop_memory_bytes`; 64, 0 for
//!   off) and `--no-loop-verify` keeps it from verifying waiting points
//!   (`PipelineConfig::loop_verify`);
//! - `--early`: early decisions (a moving instance's point stops casting
//!   rays once its AO is known to stay within the send threshold);
//!   `--early-z Z` sets their confidence (3 standard errors) and
//!   `--early-floor F` the least standard deviation they assume (0.02);
//!   `--early-audit` re-traces every early stop in full after its frame
//!   and counts the wrong ones (their full trace would have been sent);
//! - `--cull`: trace only near the viewer following the scene's camera
//!   path;
//! - `--scene NAME`: stream an embedded scene other than the default:
//!   `hall` (the procedural hall: 160 moving props, 4 walking figures) or
//!   `cesium-man` (CesiumMan alone on a floor);
//! - `--gltf PATH`: stream a scene file instead (glTF or OBJ), standing
//!   on a floor;
//! - `--frames N`, `--density D` (points spawned per square metre, half
//!   kept: `psao`'s `--density` is D / 2), `--rays N`, `--lk`
//!   (Laine-Karras estimator).
//!
//! Besides the means it prints how many steps took longer than the 60 Hz
//! period, with the median, 95th percentile and longest step.
//!
//! `cargo run --release -p psao-scene --example stream`

use std::hash::{DefaultHasher, Hasher};
use std::time::Instant;

use psao_codec::{Decoder, Event, Limits};
use psao_scene::*;

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn flag(name: &str) -> bool {
    std::env::args().any(|a| a == name)
}

/// A scene file standing on a floor 2 m wider than it on every side.
fn gltf_scene(path: &str) -> Scene {
    load_scene_file(std::path::Path::new(path))
        .and_then(stage)
        .unwrap_or_else(|e| {
            eprintln!("error: {e}");
            std::process::exit(2)
        })
}

fn main() {
    let frames: u32 = arg("--frames", 600);
    let density: f32 = arg("--density", 64.0);
    let rays: u32 = arg("--rays", 64);
    let skip = !flag("--no-skip");
    let split_bvh = !flag("--no-split");
    let gltf: String = arg("--gltf", String::new());
    let embedded: String = arg("--scene", "default".to_string());
    let (scene, name) = if !gltf.is_empty() {
        (gltf_scene(&gltf), gltf.clone())
    } else {
        match embedded.as_str() {
            "default" => (default_scene(), "default scene".to_string()),
            "hall" => (hall_scene(), "hall".to_string()),
            "cesium-man" => (cesium_man_scene(), "CesiumMan".to_string()),
            other => {
                eprintln!("error: unknown scene {other}: expected default, hall or cesium-man");
                std::process::exit(2)
            }
        }
    };
    let config = PipelineConfig {
        density,
        skip,
        split_bvh,
        cull: flag("--cull").then(ViewerCull::default),
        ray_reuse: !flag("--no-ray-reuse"),
        skip_open: !flag("--no-skip-open"),
        plan_late: flag("--plan-late"),
        loop_memory_bytes: arg::<u64>("--loop-memory-mib", 64).saturating_mul(1 << 20),
        loop_verify: !flag("--no-loop-verify"),
        budget: match arg("--ray-budget", String::new()).as_str() {
            "" => RayBudget::Unlimited,
            "auto" => RayBudget::Auto { share: 0.8 },
            n => RayBudget::Rays(n.parse().unwrap_or_else(|_| {
                eprintln!("error: --ray-budget takes a number of rays or auto");
                std::process::exit(2)
            })),
        },
        max_wait: arg("--max-wait", 8),
        max_wait_limit: arg("--max-wait-limit", 60),
        movers_every_step: flag("--movers-every-step"),
        // `--movers-whole` alone (as on `psao`) is `on`.
        movers_whole: match arg("--movers-whole", String::new()).as_str() {
            "off" => MoversWhole::Off,
            "auto" => MoversWhole::Auto,
            "on" => MoversWhole::On,
            "" if !flag("--movers-whole") => MoversWhole::Auto,
            // Alone: followed by nothing or by another option.
            v if v.is_empty() || v.starts_with("--") => MoversWhole::On,
            v => {
                eprintln!("error: --movers-whole takes off, on or auto, not {v}");
                std::process::exit(2)
            }
        },
        early: flag("--early").then(|| EarlyDecisions {
            z: arg("--early-z", 3.0),
            sd_floor: arg("--early-floor", 0.02),
            ..EarlyDecisions::default()
        }),
        ao: AoParams {
            rays,
            estimator: if flag("--lk") {
                Estimator::LaineKarras
            } else {
                Estimator::ClosestHit
            },
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let t = Instant::now();
    // When each stage of setup started.
    let stages = std::sync::Mutex::new(Vec::<(SetupStage, Instant)>::new());
    let mut server = Pipeline::with_progress(scene, config, None, &|p: SetupProgress| {
        let mut s = stages.lock().unwrap();
        if s.last().is_none_or(|l| l.0 != p.stage) {
            s.push((p.stage, Instant::now()));
        }
    })
    .unwrap_or_else(|e| {
        eprintln!("error: {e}");
        std::process::exit(2)
    });
    let setup = t.elapsed();
    // The server's process memory, before the in-process client exists.
    let server_memory = memory_kb();
    let end = t + setup;
    let stages = stages.into_inner().unwrap();
    let split: Vec<String> = stages
        .iter()
        .enumerate()
        .map(|(k, (stage, at))| {
            let until = stages.get(k + 1).map_or(end, |n| n.1);
            format!("{stage:?} {:.2} s", (until - *at).as_secs_f64())
        })
        .collect();
    let mut client = Decoder::new(Limits::default());
    let kf = server.keyframe().expect("keyframe");
    client.receive(&kf.bytes).expect("keyframe applies");
    let points: usize = (0..server.instance_count())
        .map(|i| server.points(i).map_or(0, |p| p.len()))
        .sum();
    let digest = {
        let mut h = DefaultHasher::new();
        h.write(&kf.bytes);
        h.finish()
    };
    println!(
        "{name}: {} instances, {points} points; setup (points, layout, first trace) {:.2} s; keyframe {} bytes (digest {digest:016x})",
        server.instance_count(),
        setup.as_secs_f64(),
        kf.bytes.len()
    );
    println!(
        "  setup stages       {}; {} buried points (not traced)",
        split.join(", "),
        server.buried_points()
    );
    let held = server.memory_bytes();
    println!(
        "  server memory      {:.1} MB held by the pipeline ({:.0} bytes per point)",
        held as f64 / 1e6,
        held as f64 / points.max(1) as f64
    );
    if let (Some((rss, peak)), Some((with_client, _))) = (server_memory, memory_kb()) {
        println!(
            "  process memory     {:.0} MB resident after setup ({:.0} bytes per point, with what the allocator keeps), {:.0} MB peak during setup; {:.0} MB once the in-process client holds the keyframe",
            rss as f64 * 1024.0 / 1e6,
            rss as f64 * 1024.0 / points.max(1) as f64,
            peak as f64 * 1024.0 / 1e6,
            with_client as f64 * 1024.0 / 1e6
        );
    }
    let mut sum = FrameReport::default();
    let mut sent = 0u32;
    // Every frame's bytes, in order: two runs that send the same frames
    // print the same digest.
    let mut frames_hash = DefaultHasher::new();
    let audit = flag("--early-audit");
    let (mut audited, mut audit_time) = (EarlyAudit::default(), std::time::Duration::ZERO);
    // Each step's server time, for the ticks over the period.
    let mut steps_ms = Vec::with_capacity(frames as usize);
    let t = Instant::now();
    for _ in 0..frames {
        let (frame, r) = server.step(1.0 / 60.0).expect("step");
        sum.accumulate(&r);
        steps_ms.push(r.total_time().as_secs_f64() * 1e3);
        if audit {
            let at = Instant::now();
            let a = server.early_audit().expect("audit");
            audit_time += at.elapsed();
            audited.checked += a.checked;
            audited.wrong += a.wrong;
            audited.worst_steps = audited.worst_steps.max(a.worst_steps);
        }
        if let Some(f) = frame {
            sent += 1;
            frames_hash.write(&f.bytes);
            let e = client.receive(&f.bytes).expect("valid frame");
            assert!(matches!(e, Event::Applied { .. }), "{e:?}");
        }
    }
    let wall = (t.elapsed() - audit_time).as_secs_f64();
    let n = frames as f64;
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3 / n;
    for i in 0..server.instance_count() {
        let (t, m) = (
            server.table(i).expect("table"),
            client.mirror().instance(i as u32).expect("mirror"),
        );
        assert!(
            t.words() == m.words() && t.buckets() == m.buckets(),
            "instance {i} differs"
        );
    }
    println!(
        "{frames} frames at 60 Hz ({:.1} s of scene), {sent} sent, {wall:.2} s wall; skip {}, BVH {}, culling {}, {} rays/point {:?}",
        n / 60.0,
        if skip { "on" } else { "off" },
        if split_bvh { "split" } else { "whole" },
        if config_cull(&server) { "on" } else { "off" },
        rays,
        server_estimator(&server),
    );
    println!(
        "  points traced      {:.0} per frame ({:.1}% of {points})",
        sum.traced as f64 / n,
        100.0 * sum.traced as f64 / n / points as f64
    );
    println!(
        "  rays               {:.0} per frame, {:.2} Mrays/s while tracing",
        sum.rays as f64 / n,
        sum.rays as f64 / sum.t_trace.as_secs_f64().max(1e-9) / 1e6
    );
    println!(
        "  known open         {:.0} points per frame traced without a ray (nothing within reach of their rays)",
        sum.open as f64 / n
    );
    println!(
        "  ray reuse          {:.0} points per frame within reach but no ray reached, {:.0} rays per frame kept from the last trace; {} points with kept scores",
        sum.unreached as f64 / n,
        sum.rays_kept as f64 / n,
        server.kept_ray_points()
    );
    if let Some((period, points, bytes)) = server.loop_memory() {
        println!(
            "  loop memory        the scene loops every {period:.3} s; {points} points remembered in {:.1} MB; {:.1} waiting points per frame verified (not behind a full re-trace, their wait started again)",
            bytes as f64 / 1e6,
            sum.verified as f64 / n
        );
    }
    if let Some(b) = sum.budget {
        println!(
            "  ray budget         {:.0} rays per frame; {} points waiting at the end, the longest wait {} frames (bound up to {}); {:.1} points per frame traced past the budget (overdue)",
            b as f64 / n,
            sum.waiting,
            sum.oldest_wait,
            sum.wait_bound,
            sum.overdue as f64 / n
        );
    }
    if server.config().early.is_some() {
        println!(
            "  early decisions    {:.0} points per frame stopped early (nothing to send)",
            sum.early as f64 / n
        );
    }
    if audit {
        println!(
            "  early audit        {} stops traced again in full: {} would have been sent ({:.3}%); the largest gap to what clients hold {} steps of 1/255 (threshold {})",
            audited.checked,
            audited.wrong,
            100.0 * audited.wrong as f64 / audited.checked.max(1) as f64,
            audited.worst_steps,
            server.config().thresholds.ao_steps
        );
    }
    println!(
        "  points sent        {:.0} per frame (past the thresholds; dropped points retry)",
        sum.updated as f64 / n
    );
    println!(
        "  bit rate           {:.3} Mbit/s",
        sum.bytes as f64 * 8.0 / (n / 60.0) / 1e6
    );
    println!(
        "  points culled      {:.0} per frame waiting out of view",
        sum.culled as f64 / n
    );
    // Points without a slot now, and the drop events by reason (a point
    // that retries and drops again counts again).
    let stats: Vec<_> = (0..server.instance_count())
        .filter_map(|i| server.table(i).map(|t| t.stats()))
        .collect();
    let total = |f: fn(&psao_codec::TableStats) -> u64| stats.iter().map(f).sum::<u64>();
    println!(
        "  points dropped     {} without a slot now; drop events: {} cell full, {} bucket full, {} pool exhausted, {} out of the grid",
        total(|s| s.dropped as u64),
        total(|s| s.cell_overflow),
        total(|s| s.bucket_overflow),
        total(|s| s.pool_exhausted),
        total(|s| s.out_of_grid)
    );
    println!(
        "  per traced point   {:.3} us of server time ({:.3} us tracing)",
        sum.total_time().as_secs_f64() * 1e6 / (sum.traced as f64).max(1.0),
        sum.t_trace.as_secs_f64() * 1e6 / (sum.traced as f64).max(1.0)
    );
    println!(
        "  server ms/frame    {:.3} total: {:.3} animate + skin, {:.3} select, {:.3} BVH, {:.3} trace, {:.3} tables + encode",
        ms(sum.total_time()),
        ms(sum.t_animate),
        ms(sum.t_select),
        ms(sum.t_bvh),
        ms(sum.t_trace),
        ms(sum.t_encode)
    );
    steps_ms.sort_by(f64::total_cmp);
    let period_ms = 1e3 / 60.0;
    let over = steps_ms.iter().filter(|&&x| x > period_ms).count();
    let at = |q: f64| {
        let i = ((steps_ms.len() as f64 * q).ceil() as usize).clamp(1, steps_ms.len().max(1));
        steps_ms.get(i - 1).copied().unwrap_or(0.0)
    };
    println!(
        "  ticks over period  {over} of {} over {period_ms:.3} ms (median {:.3}, 95th percentile {:.3}, longest {:.3} ms)",
        steps_ms.len(),
        at(0.5),
        at(0.95),
        at(1.0)
    );
    let ph = sum.trace_phases;
    println!(
        "  trace ms/frame     {:.3} plan, {:.3} choose, {:.3} cast, {:.3} apply + fill",
        ms(ph.plan),
        ms(ph.choose),
        ms(ph.cast),
        ms(ph.apply)
    );
    println!(
        "  client mirror      equal to the server's tables; frames digest {:016x}",
        frames_hash.finish()
    );
}

/// Resident and peak resident memory of this process in KiB (Linux).
fn memory_kb() -> Option<(u64, u64)> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))?
            .split_whitespace()
            .nth(1)?
            .parse::<u64>()
            .ok()
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

fn config_cull(server: &Pipeline) -> bool {
    server.config().cull.is_some()
}

fn server_estimator(server: &Pipeline) -> Estimator {
    server.config().ao.estimator
}
