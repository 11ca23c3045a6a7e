//! `psao demo`: the reference server and its clients in one process over
//! loopback QUIC, on the embedded default scene, with a live status line,
//! AO images from the first client's mirror and a summary that checks
//! every mirror against the server's tables.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::bail;
use indicatif::{ProgressBar, ProgressStyle};
use psao_codec::Limits;
use psao_proto::tls::fingerprint_hex;
use psao_proto::{
    ClientConfig, ClientHandle, Ended, Identity, ServerConfig, ServerHandle, ServerStats, Trust,
    connect, serve,
};
use psao_scene::{Pipeline, PipelineConfig, ViewerCull, default_scene};

use super::common::{CameraArgs, cpu_seconds, pipeline_config, pipeline_with_progress, status};
use super::shots::Shots;

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
    summarize(server, handles, start, wall, cpu, rate).await
}

/// The summary's line on the server's schedule between `start` and `end`
/// (rate::TickSchedule), for a server of `rate` ticks a second.
pub(super) fn schedule_line(start: &ServerStats, end: &ServerStats, rate: u16) -> String {
    format!(
        "  schedule            {} ticks started behind it (at most {:.0} ms behind were made up), {} given up; since the server started: at most {:.1} ms behind, longest step {:.1} ms",
        end.behind_ticks - start.behind_ticks,
        psao_proto::rate::catch_up_limit(rate).as_secs_f64() * 1e3,
        end.lost_ticks - start.lost_ticks,
        end.most_behind.as_secs_f64() * 1e3,
        end.longest_step.as_secs_f64() * 1e3
    )
}

/// Stops the server, waits for the clients to apply its last frame,
/// checks their mirrors against its tables and prints the figures.
async fn summarize(
    server: ServerHandle<Pipeline>,
    handles: Vec<ClientHandle>,
    start: ServerStats,
    wall: f64,
    cpu: Option<f64>,
    rate: u16,
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
    println!("{}", schedule_line(&start, &end, rate));
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
