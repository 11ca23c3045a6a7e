//! `psao demo`: the reference server and its clients in one process over
//! loopback QUIC, on the embedded default scene, with a live status line,
//! AO images from the first client's mirror and a summary that checks
//! every mirror against the server's tables.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use indicatif::{ProgressBar, ProgressStyle};
use psao_codec::Limits;
use psao_eval::{PosedScene, View, psao_image};
use psao_proto::tls::fingerprint_hex;
use psao_proto::{
    ClientConfig, ClientHandle, Ended, Identity, ServerConfig, ServerHandle, ServerStats, Trust,
    connect, serve,
};
use psao_scene::{Pipeline, PipelineConfig, Scene, ViewerCull, default_scene};

use super::common::{CameraArgs, cpu_seconds, pipeline_config, pipeline_with_progress, status};
use crate::bench::images::{ao_png16, composite};

/// Arguments of `psao demo`.
#[derive(clap::Args)]
pub struct Args {
    /// Seconds of scene to stream.
    #[arg(long, default_value_t = 10.0)]
    seconds: f32,
    /// Server frames per second.
    #[arg(long, default_value_t = 60)]
    rate: u16,
    /// Clients to connect.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=1000))]
    clients: u16,
    /// Points kept per square metre (the paper's N, as in `psao bench
    /// --densities`).
    #[arg(long, default_value_t = 32.0)]
    density: f32,
    /// AO radius R in scene units (the default is the paper's, in metres).
    #[arg(long, default_value_t = 0.6)]
    radius: f32,
    /// AO rays per point.
    #[arg(long, default_value_t = 64)]
    rays: u32,
    /// AO images of the camera path the first client renders from its
    /// mirror, spread over the run (0: none).
    #[arg(long, default_value_t = 4)]
    images: u32,
    /// Folder for the images.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
    /// The server culls to its clients' views; the clients are viewers
    /// that send the camera path's pose as they go.
    #[arg(long)]
    cull: bool,
    /// The camera the images (and, with --cull, the viewers) follow.
    #[command(flatten)]
    camera: CameraArgs,
    #[command(flatten)]
    budget: super::common::BudgetArgs,
    #[command(flatten)]
    lead: super::common::LeadArgs,
    /// A mirror digest (spec/session.md 3.8) every this many frames to
    /// each client, which checks it (0: no digests).
    #[arg(long, default_value_t = psao_proto::server::DIGEST_INTERVAL)]
    digest_interval: u16,
    /// Fan out through Media over QUIC relays instead: start two clustered
    /// moq-relay processes on loopback, publish the broadcast to the first
    /// and subscribe the clients through both (spec/moq.md).
    #[arg(long, conflicts_with = "cull")]
    relay: bool,
    /// The moq-relay binary for --relay [default: $PSAO_MOQ_RELAY, or
    /// moq-relay on the PATH].
    #[arg(long, requires = "relay")]
    relay_bin: Option<PathBuf>,
}

/// Runs the demo: streams, prints, writes images, checks the mirrors.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        seconds,
        rate,
        clients,
        density,
        radius,
        rays,
        images,
        out,
        cull,
        camera,
        budget,
        lead,
        digest_interval,
        relay,
        relay_bin,
    } = args;
    if !(seconds > 0.0 && seconds <= 3600.0) {
        bail!("--seconds must be in (0, 3600]");
    }
    let clients = clients as usize;
    let mut scene = default_scene();
    if let Some(path) = camera.path()? {
        scene.camera = Some(path);
    }
    let mut shots = Shots::new(images, out, scene.clone())?;
    let identity = Identity::self_signed()?;
    let config = ServerConfig {
        frame_rate: rate,
        digest_interval,
        ..ServerConfig::default()
    };
    let mut pipeline = PipelineConfig {
        cull: cull.then(ViewerCull::default),
        ..pipeline_config(density, rays, radius)
    };
    budget.apply(&mut pipeline);
    lead.apply(&mut pipeline, rate);
    let lead = pipeline.lead;
    println!("psao demo: preparing the default scene (points, grids, first trace)...");
    let t = Instant::now();
    let pipeline = pipeline_with_progress(scene, pipeline)?;
    if relay {
        let demo = super::demo_relay::RelayDemo {
            seconds,
            rate,
            clients,
            digest_interval,
            shots,
            lead,
            relay_bin,
        };
        return super::demo_relay::run(demo, pipeline).await;
    }
    let server = serve(pipeline, config, &identity).await?;
    println!(
        "server on {} (self-signed certificate, SHA-256 {}), ready in {:.2} s",
        server.local_addr(),
        fingerprint_hex(&server.fingerprint()),
        t.elapsed().as_secs_f64()
    );
    let trust = Trust::Fingerprint(server.fingerprint());
    let mut handles = Vec::new();
    for _ in 0..clients {
        let h = connect(
            server.local_addr(),
            &trust,
            ClientConfig {
                limits: Limits::default(),
                viewer: cull,
                ..ClientConfig::default()
            },
            Duration::from_secs(10),
        )
        .await?;
        handles.push(h);
    }
    let welcome = handles[0].with_session(|s| s.welcome().cloned());
    if let Some(w) = welcome {
        println!(
            "{} client(s) joined: scene `{}`, {} Hz, compression {}",
            clients, w.scene, w.frame_rate, w.compression
        );
    }
    let total = (seconds * rate as f32).round() as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos:>5}/{len} frames  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let start = server.stats();
    let (started, cpu0) = (Instant::now(), cpu_seconds());
    let mut prev = (start.clone(), Instant::now());
    // Without a terminal the bar is hidden: print a line a second instead.
    let mut printed = Instant::now();
    loop {
        tokio::time::sleep(Duration::from_millis(250)).await;
        let s = server.stats();
        let frames = s.frames - start.frames;
        bar.set_position(frames.min(total));
        let dt = prev.1.elapsed().as_secs_f64();
        let line = status(&s, &prev.0, dt);
        if bar.is_hidden() {
            if printed.elapsed() >= Duration::from_secs(1) {
                println!("{line}");
                printed = Instant::now();
            }
        } else {
            bar.set_message(line);
        }
        // Scene time: the server steps from its start, before clients join.
        let t = s.frames as f32 / rate as f32;
        prev = (s, Instant::now());
        if cull {
            // Viewers follow the camera path and say so.
            if let Some(path) = &shots.scene.camera {
                let c = path.at(t);
                for h in &handles {
                    h.send_camera(psao_proto::control::CameraPose {
                        time_ms: (t * 1000.0) as u32,
                        eye: c.eye,
                        target: c.target,
                        fov_y: c.fov_y,
                        aspect: 16.0 / 9.0,
                    });
                }
            }
        }
        while shots.due(frames, total) {
            let mirror = handles[0].with_session(|s| s.mirror().clone());
            // The mirror holds the scene posed `lead` ahead of its tick.
            let line = shots.take(mirror, t + lead).await?;
            bar.println(line);
        }
        if frames >= total {
            break;
        }
        if handles.iter().any(|h| h.ended() != Ended::Running) {
            bar.abandon();
            bail!("a client's session ended early");
        }
    }
    bar.finish();
    let wall = started.elapsed().as_secs_f64();
    let cpu = cpu_seconds().zip(cpu0).map(|(a, b)| a - b);
    summarize(server, handles, start, wall, cpu).await
}

/// The AO images `psao demo` writes: what the first client shows at
/// moments of the camera path, reconstructed from its mirror on a
/// G-buffer of the scene at that moment (the client renders the scene
/// itself and takes AO from the mirror, as a split renderer does).
pub struct Shots {
    count: u32,
    taken: u32,
    out: PathBuf,
    scene: Arc<Scene>,
}

/// Size of the demo's images.
const SHOT_SIZE: (u32, u32) = (480, 270);

impl Shots {
    /// `count` images of `scene` into `out` (created now, so a bad path
    /// fails early).
    fn new(count: u32, out: PathBuf, scene: Scene) -> anyhow::Result<Shots> {
        if count > 0 {
            std::fs::create_dir_all(&out)
                .with_context(|| format!("cannot create {}", out.display()))?;
        }
        Ok(Shots {
            count,
            taken: 0,
            out,
            scene: Arc::new(scene),
        })
    }

    /// Whether the next image is due after `frames` of `total`: images
    /// fall at the ends of `count` equal parts of the run.
    pub fn due(&self, frames: u64, total: u64) -> bool {
        self.taken < self.count && frames * self.count as u64 >= total * (self.taken as u64 + 1)
    }

    /// Renders and writes the image at scene time `t` from `mirror`;
    /// returns a line saying where it went.
    pub async fn take(&mut self, mirror: psao_codec::Mirror, t: f32) -> anyhow::Result<String> {
        self.taken += 1;
        let (scene, out, k) = (self.scene.clone(), self.out.clone(), self.taken);
        tokio::task::spawn_blocking(move || -> anyhow::Result<String> {
            let path = scene
                .camera
                .as_ref()
                .context("the scene has no camera path")?;
            let view = View::new(path.at(t), SHOT_SIZE.0, SHOT_SIZE.1)?;
            let posed = PosedScene::new(&scene, t)?;
            let g = posed.gbuffer(&view);
            let image = psao_image(&mirror, &g)?;
            let ao = out.join(format!("demo-{k:02}-ao.png"));
            ao_png16(&image.ao, view.width, view.height)
                .save(&ao)
                .with_context(|| ao.display().to_string())?;
            let lit = out.join(format!("demo-{k:02}-lit.png"));
            image::RgbImage::from_raw(view.width, view.height, composite(&g, &image.ao))
                .context("image size")?
                .save(&lit)
                .with_context(|| lit.display().to_string())?;
            Ok(format!(
                "image {k}: t = {t:.2} s, AO from the client's mirror (sequence {}) -> {} and {}",
                mirror.sequence().map_or("none".into(), |s| s.to_string()),
                ao.display(),
                lit.display()
            ))
        })
        .await
        .context("image task")?
    }
}

/// Stops the server, waits for the clients to apply its last frame,
/// checks their mirrors against its tables and prints the figures.
async fn summarize(
    server: ServerHandle<Pipeline>,
    handles: Vec<ClientHandle>,
    start: ServerStats,
    wall: f64,
    cpu: Option<f64>,
) -> anyhow::Result<()> {
    let (pipeline, end) = server.shutdown(Duration::from_secs(2)).await?;
    let last = end.sequence;
    let mut in_sync = 0;
    for h in &handles {
        let reached = h
            .wait_for(Duration::from_secs(5), |s| {
                s.mirror().sequence() == Some(last)
            })
            .await;
        let same = reached
            && h.with_session(|s| {
                (0..pipeline.instance_count()).all(|i| {
                    let t = pipeline.table(i).expect("instance");
                    s.mirror()
                        .instance(i as u32)
                        .is_some_and(|m| m.words() == t.words() && m.buckets() == t.buckets())
                })
            });
        in_sync += same as usize;
    }
    let frames = (end.frames - start.frames).max(1) as f64;
    // Work over the streaming window (after every client joined), not
    // the joining.
    let secs = (end.step_time - start.step_time).as_secs_f64();
    let stats: Vec<_> = handles
        .iter()
        .map(|h| h.with_session(|s| s.stats()))
        .collect();
    println!();
    println!("summary");
    println!(
        "  server frames       {} stepped in {wall:.2} s ({:.1} fps), {} with news, {} keyframes",
        end.frames,
        (end.frames - start.frames) as f64 / wall,
        end.sent_frames,
        end.keyframes
    );
    if let Some(cpu) = cpu {
        println!(
            "  process CPU         {cpu:.2} s over {wall:.2} s ({:.0}% of one core; server and {} client(s) together)",
            100.0 * cpu / wall,
            handles.len()
        );
    }
    println!(
        "  per client          {:.3} Mbit/s over the streaming window",
        (end.written_bytes - start.written_bytes) as f64 * 8.0
            / wall
            / 1e6
            / handles.len().max(1) as f64
    );
    println!(
        "  server work         {:.2} ms/frame stepping ({:.0} points traced, {:.0} sent, {:.0} waiting out of view per frame)",
        secs * 1e3 / frames,
        (end.report.traced - start.report.traced) as f64 / frames,
        (end.report.updated - start.report.updated) as f64 / frames,
        (end.report.culled - start.report.culled) as f64 / frames
    );
    println!(
        "  bytes               {} encoded once, {} written to {} client(s)",
        end.encoded_bytes,
        end.written_bytes,
        handles.len()
    );
    for (k, s) in stats.iter().enumerate() {
        println!(
            "  client {k}            {} frames applied ({} keyframes), {} failed, {} stale, {} keyframe requests, {:.1} kB received, digests {} matched / {} differed",
            s.applied,
            s.keyframes,
            s.failed,
            s.stale,
            s.requests,
            s.bytes as f64 / 1e3,
            s.digests_matched,
            s.digest_mismatches
        );
    }
    println!(
        "  frame age           {:.1} ms (send to ACK, mean over clients)",
        end.frame_age * 1e3
    );
    println!(
        "  mirrors             {in_sync} of {} equal to the server's tables at sequence {last}",
        handles.len()
    );
    for h in handles {
        h.close().await;
    }
    if in_sync == stats.len() {
        Ok(())
    } else {
        Err(anyhow::anyhow!("a client's mirror differs from the server"))
    }
}
