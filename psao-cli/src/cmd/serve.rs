//! `psao serve`: the reference server for clients elsewhere, with a status
//! line a second, until Ctrl-C or `--seconds`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use psao_moq::net::{Link, RelayUrl};
use psao_proto::tls::fingerprint_hex;
use psao_proto::{FrameSource, Identity, ServerConfig, serve};
use psao_scene::{Pipeline, PipelineConfig, ViewerCull};

use super::common::{load_scene, pipeline_config, pipeline_with_progress, seconds_of, status};
use super::web::{WebPlan, WebRunning};

/// Arguments of `psao serve`.
#[derive(clap::Args)]
pub struct Args {
    /// A scene file, glTF (.gltf, .glb) or OBJ, or an embedded scene:
    /// `default`, `hall` (160 moving props, 4 walking figures) or
    /// `cesium-man` [default: the embedded default scene].
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Address to listen on.
    #[arg(long, default_value = "0.0.0.0:4433")]
    bind: SocketAddr,
    /// PEM certificate chain [default: a generated self-signed one].
    #[arg(long, requires = "key")]
    cert: Option<PathBuf>,
    /// PEM private key of --cert (required with it).
    #[arg(long, requires = "cert")]
    key: Option<PathBuf>,
    /// Frames per second.
    #[arg(long, default_value_t = 60)]
    rate: u16,
    /// Most clients at once.
    #[arg(long, default_value_t = 256)]
    max_clients: usize,
    /// Most bytes queued for one client before it is resynchronized.
    #[arg(long, default_value_t = 1 << 20)]
    queue_bytes: usize,
    /// A mirror digest (spec/session.md 3.8) every this many frames to
    /// each client that checks digests (0: digests not offered).
    #[arg(long, default_value_t = psao_proto::server::DIGEST_INTERVAL)]
    digest_interval: u16,
    /// Points kept per square metre (the paper's N, as in `psao bench
    /// --densities`).
    #[arg(long, default_value_t = 32.0)]
    density: f32,
    /// AO rays per point.
    #[arg(long, default_value_t = 64)]
    rays: u32,
    /// AO radius R in scene units (the default is the paper's, in metres).
    #[arg(long, default_value_t = 0.6)]
    radius: f32,
    /// Stop after this many seconds [default: until Ctrl-C].
    #[arg(long)]
    seconds: Option<f32>,
    /// Cull to the clients' views: trace only points near what the
    /// viewers' CAMERA messages say they see (spec/session.md 3.2).
    #[arg(long)]
    cull: bool,
    /// Keep deforming (skinned, morphing) meshes' points posed, moved and
    /// re-sent with every pose (point format 0 only), for clients that do
    /// not know point format 1 (bind space, spec/wire-format.md 6.1).
    #[arg(long)]
    posed_deforming: bool,
    /// Drop the points a full cell has no slot for instead of continuing
    /// it in an overflow chain (spec/wire-format.md 7.4), for clients that
    /// do not offer chains in their HELLO.
    #[arg(long)]
    no_overflow: bool,
    #[command(flatten)]
    budget: super::common::BudgetArgs,
    #[command(flatten)]
    lead: super::common::LeadArgs,
    #[command(flatten)]
    publish: super::relay::PublishArgs,
    #[command(flatten)]
    web: super::web::WebArgs,
}

/// What the server holds for the scene, in a line: triangles, instances
/// (how many move), points, keyframe bytes, pipeline memory, the process's
/// resident memory, setup time.
fn scene_summary(p: &mut Pipeline, setup_s: f64) -> anyhow::Result<String> {
    let scene = p.scene();
    let triangles: usize = scene
        .instances
        .iter()
        .map(|i| scene.meshes[i.mesh].triangle_count())
        .sum();
    let instances = p.instance_count();
    let moving = (0..instances).filter(|&i| p.is_dynamic(i)).count();
    let points: usize = (0..instances)
        .map(|i| p.points(i).map_or(0, |s| s.len()))
        .sum();
    let memory = p.memory_bytes();
    // Measured before the keyframe is encoded, as the pipeline stands.
    let process = crate::memory::resident().map_or(String::new(), |(rss, peak)| {
        format!(
            "; process {:.1} MB resident ({:.0} bytes per point), {:.1} MB at its peak",
            rss as f64 / 1e6,
            rss as f64 / points.max(1) as f64,
            peak as f64 / 1e6
        )
    });
    let keyframe = p.keyframe()?.bytes.len();
    // Under a budget, whether the scene loops (the loop memory ranks by it).
    let looping = p.loop_memory().map_or(String::new(), |(period, _, _)| {
        format!("; the animation loops every {period:.3} s (--loop-memory-mib)")
    });
    Ok(format!(
        "scene ready in {setup_s:.1} s: {triangles} triangles, {instances} instances ({moving} moving), \
         {points} points, keyframe {:.1} kB, {:.1} MB held by the pipeline ({:.0} bytes per point){process}{looping}",
        keyframe as f64 / 1e3,
        memory as f64 / 1e6,
        memory as f64 / points.max(1) as f64
    ))
}

/// Serves until Ctrl-C or `--seconds`, printing a status line a second.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let identity = match (&args.cert, &args.key) {
        (Some(c), Some(k)) => Identity::from_pem_files(c, k)?,
        _ => Identity::self_signed()?,
    };
    let (scene, name) = load_scene(args.scene.as_deref())?;
    let config = ServerConfig {
        bind: args.bind,
        frame_rate: args.rate,
        max_clients: args.max_clients,
        max_queue_bytes: args.queue_bytes,
        digest_interval: args.digest_interval,
        scene_name: name,
        ..ServerConfig::default()
    };
    // Checked before the scene is prepared, so a bad option fails at once.
    let publish = args.publish.options(
        &config.scene_name,
        config.frame_rate,
        config.digest_interval,
    )?;
    if publish.is_some() && args.cull {
        anyhow::bail!(
            "--publish with --cull: a broadcast carries the whole scene to every viewer (spec/moq.md 6)"
        );
    }
    let mut pipeline = PipelineConfig {
        cull: args.cull.then(ViewerCull::default),
        bind_space: !args.posed_deforming,
        ..pipeline_config(args.density, args.rays, args.radius)
    };
    pipeline.layout.overflow = !args.no_overflow;
    args.budget.apply(&mut pipeline);
    args.lead.apply(&mut pipeline, args.rate);
    for w in super::common::scale_warnings(&scene, args.density, args.radius)? {
        eprintln!("warning: {w}");
    }
    println!("preparing the scene (points, grids, first trace)...");
    let started = Instant::now();
    let mut pipeline = pipeline_with_progress(scene, pipeline)?;
    println!(
        "{}",
        scene_summary(&mut pipeline, started.elapsed().as_secs_f64())?
    );
    let web = args.web.plan(&pipeline, &config.scene_name)?;
    match publish {
        None => serve_until(pipeline, config, &identity, None, web, args.seconds).await,
        Some(options) => {
            let (publishing, link) = psao_moq::net::publish_alongside(pipeline, &options).await?;
            println!(
                "publishing broadcast {} to {}; follow it with: psao view --subscribe {} --fingerprint HEX (the relay's)",
                link.broadcast(),
                options.relay,
                RelayUrl {
                    path: link.broadcast().to_string(),
                    ..options.relay.clone()
                }
            );
            serve_until(publishing, config, &identity, Some(link), web, args.seconds).await
        }
    }
}

/// The next certificate of the browser side, installed (never, without
/// one).
async fn next_certificate<S: FrameSource>(
    web: &mut Option<WebRunning>,
    server: &psao_proto::ServerHandle<S>,
) {
    match web {
        Some(w) => w.next_certificate(server).await,
        None => std::future::pending().await,
    }
}

/// Serves `source` until Ctrl-C or `seconds`, a status line a second (with
/// the broadcast's figures when it also publishes).
async fn serve_until<S: FrameSource>(
    source: S,
    config: ServerConfig,
    identity: &Identity,
    link: Option<Link>,
    web: Option<WebPlan>,
    seconds: Option<f32>,
) -> anyhow::Result<()> {
    let rate = config.frame_rate;
    let mut server = serve(source, config, identity).await?;
    println!("listening on {}", server.local_addr());
    println!(
        "certificate SHA-256 {}",
        fingerprint_hex(&server.fingerprint())
    );
    println!(
        "connect with: psao view --connect {} --fingerprint {}",
        server.local_addr(),
        fingerprint_hex(&server.fingerprint())
    );
    let mut web = match web {
        Some(plan) => Some(plan.start(&mut server, rate).await?),
        None => None,
    };
    let until = seconds.map(|s| Instant::now() + seconds_of(s));
    let mut ticks = 0u64;
    let mut prev = (server.stats(), Instant::now());
    let mut prev_link = link.as_ref().map(|l| l.stats());
    loop {
        tokio::select! {
            _ = tokio::signal::ctrl_c() => break,
            _ = next_certificate(&mut web, &server) => {}
            _ = tokio::time::sleep(Duration::from_secs(1)) => {
                let s = server.stats();
                let dt = prev.1.elapsed().as_secs_f64();
                let mut line = status(&s, &prev.0, dt);
                // Ticks a second against the rate WELCOME announced.
                let fps = (s.frames - prev.0.frames) as f64 / dt;
                if fps < 0.95 * rate as f64 {
                    line.push_str(&format!(" | BEHIND: {fps:.1} of {rate} Hz"));
                    tracing::warn!(
                        "the server runs at {fps:.1} frames/s, below the {rate} Hz its WELCOME announced (step {:.1} ms)",
                        (s.step_time - prev.0.step_time).as_secs_f64() * 1e3
                            / (s.frames - prev.0.frames).max(1) as f64
                    );
                }
                let lost = s.lost_ticks - prev.0.lost_ticks;
                if lost > 0 {
                    // More than rate::catch_up_limit behind: ticks given up.
                    line.push_str(&format!(" | {lost} ticks given up"));
                }
                if let (Some(l), Some(p)) = (&link, &prev_link) {
                    let now = l.stats();
                    line.push_str(&format!(
                        " | relay: {}, {:.3} Mbit/s, group {}",
                        if now.connected { "up" } else { "DOWN" },
                        (now.broadcast.frame_bytes - p.broadcast.frame_bytes) as f64 * 8.0 / dt / 1e6,
                        now.broadcast.groups.saturating_sub(1),
                    ));
                    prev_link = Some(now);
                }
                println!("{line}");
                ticks += 1;
                if web.is_some() && ticks.is_multiple_of(5) {
                    println!("clients by binding: {}", super::web::binding_summary(&server.client_figures()));
                }
                prev = (s, Instant::now());
                if until.is_some_and(|u| Instant::now() >= u) {
                    break;
                }
            }
        }
    }
    if web.is_some() {
        println!(
            "clients by binding: {}",
            super::web::binding_summary(&server.client_figures())
        );
    }
    println!("shutting down");
    drop(web);
    // The source back first: a publishing one finishes its tracks as it
    // goes, then the broadcast ends cleanly.
    let (source, _) = server.shutdown(Duration::from_secs(2)).await?;
    drop(source);
    if let Some(l) = link {
        l.close().await;
    }
    Ok(())
}
