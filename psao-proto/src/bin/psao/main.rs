//! `psao`: the PSAO command line.
//!
//! - `psao demo`: server and client in one process over loopback QUIC on
//!   the embedded default scene, with a live status line and a summary;
//! - `psao serve`: a server for clients elsewhere;
//! - `psao view`: a headless client;
//! - `psao record`: a client that writes what it receives to a capture
//!   file (spec/capture.md);
//! - `psao inspect`: decodes a capture file frame by frame.
//! - `psao bench`: accuracy against run time (PSAO, per-pixel RTAO, SAO
//!   against a ray-traced reference), with a CSV, a markdown table, charts
//!   and a side-by-side image.

mod bench;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use psao_codec::Limits;
use psao_proto::tls::{fingerprint_hex, parse_fingerprint};
use psao_proto::{
    ClientConfig, ClientHandle, Ended, Identity, ServerConfig, ServerHandle, ServerStats, Trust,
    connect, serve,
};
use std::sync::Arc;

use psao_scene::{
    AoParams, PipelineConfig, PosedScene, Scene, View, ViewerCull, default_scene, load_gltf,
    psao_image,
};

#[derive(Parser)]
#[command(
    name = "psao",
    version,
    about = "Point-based split ambient occlusion: server, client and demo"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Server and clients in one process over loopback QUIC, on the
    /// embedded default scene; prints live figures and a summary.
    Demo {
        /// Seconds of scene to stream.
        #[arg(long, default_value_t = 10.0)]
        seconds: f32,
        /// Server frames per second.
        #[arg(long, default_value_t = 60)]
        rate: u16,
        /// Clients to connect.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=1000))]
        clients: u16,
        /// Points spawned per square metre (half are kept).
        #[arg(long, default_value_t = 64.0)]
        density: f32,
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
    },
    /// Serve a scene to clients.
    Serve {
        /// A glTF file (default: the embedded default scene).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Address to listen on.
        #[arg(long, default_value = "0.0.0.0:4433")]
        bind: SocketAddr,
        /// PEM certificate chain (default: a generated self-signed one).
        #[arg(long, requires = "key")]
        cert: Option<PathBuf>,
        /// PEM private key of --cert.
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
        /// Points spawned per square metre (half are kept).
        #[arg(long, default_value_t = 64.0)]
        density: f32,
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        seconds: Option<f32>,
        /// Cull to the clients' views: trace only points near what the
        /// viewers' CAMERA messages say they see (spec/session.md 3.2).
        #[arg(long)]
        cull: bool,
    },
    /// Connect to a server and keep a mirror in sync, printing figures.
    View {
        #[command(flatten)]
        server: ServerArgs,
    },
    /// Connect to a server and write every frame received to a capture
    /// file (spec/capture.md).
    Record {
        #[command(flatten)]
        server: ServerArgs,
        /// The capture file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Accuracy against run time: PSAO at several densities and server
    /// rates, per-pixel RTAO and SAO against a per-pixel ray-traced
    /// reference; writes bench.csv, bench.md, charts and images.
    Bench(bench::BenchArgs),
    /// Decode a capture file frame by frame and print what each frame is
    /// and does to a mirror.
    Inspect {
        /// The capture file.
        file: PathBuf,
        /// Print only the summary.
        #[arg(long)]
        quiet: bool,
    },
}

/// Where a client connects and how it trusts the server.
#[derive(clap::Args)]
struct ServerArgs {
    /// The server.
    #[arg(long)]
    connect: SocketAddr,
    /// SHA-256 fingerprint of the server's certificate (as `psao serve`
    /// prints it).
    #[arg(long, conflicts_with = "ca")]
    fingerprint: Option<String>,
    /// PEM file of certificates to trust instead.
    #[arg(long)]
    ca: Option<PathBuf>,
    /// With --ca: the name the server's certificate must carry (default
    /// localhost).
    #[arg(long, requires = "ca")]
    name: Option<String>,
    /// Stop after this many seconds (default: until the server closes).
    #[arg(long)]
    seconds: Option<f32>,
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = runtime.block_on(async {
        match cli.command {
            Command::Demo {
                seconds,
                rate,
                clients,
                density,
                rays,
                images,
                out,
                cull,
            } => {
                let shots = Shots::new(images, out)?;
                let clients = clients as usize;
                demo(seconds, rate, clients, density, rays, shots, cull).await
            }
            Command::Serve {
                scene,
                bind,
                cert,
                key,
                rate,
                max_clients,
                queue_bytes,
                density,
                seconds,
                cull,
            } => {
                let identity = match (cert, key) {
                    (Some(c), Some(k)) => {
                        Identity::from_pem_files(&c, &k).map_err(|e| e.to_string())?
                    }
                    _ => Identity::self_signed().map_err(|e| e.to_string())?,
                };
                let (scene, name) = load_scene(scene.as_deref())?;
                let config = ServerConfig {
                    bind,
                    frame_rate: rate,
                    max_clients,
                    max_queue_bytes: queue_bytes,
                    pipeline: PipelineConfig {
                        cull: cull.then(ViewerCull::default),
                        ..pipeline_config(density, 64)
                    },
                    scene_name: name,
                    ..ServerConfig::default()
                };
                serve_until_stopped(scene, config, &identity, seconds).await
            }
            Command::View { server } => {
                let trust = trust_of(server.fingerprint, server.ca, server.name)?;
                view(server.connect, &trust, server.seconds).await
            }
            Command::Record { server, out } => {
                let trust = trust_of(server.fingerprint, server.ca, server.name)?;
                record(server.connect, &trust, &out, server.seconds).await
            }
            Command::Inspect { file, quiet } => inspect(&file, quiet),
            Command::Bench(args) => bench::run(args),
        }
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// A duration of `s` seconds, clamped to [0, 10^7] (NaN reads as 0).
fn seconds_of(s: f32) -> Duration {
    Duration::from_secs_f32(if s.is_nan() { 0.0 } else { s.clamp(0.0, 1e7) })
}

fn trust_of(
    fingerprint: Option<String>,
    ca: Option<PathBuf>,
    name: Option<String>,
) -> Result<Trust, String> {
    match (fingerprint, ca) {
        (Some(f), _) => Ok(Trust::Fingerprint(
            parse_fingerprint(&f).map_err(|e| e.to_string())?,
        )),
        (None, Some(ca)) => Ok(Trust::Roots {
            roots: read_roots(&ca)?,
            name: name.unwrap_or_else(|| "localhost".into()),
        }),
        (None, None) => Err("give --fingerprint (printed by `psao serve`) or --ca".into()),
    }
}

async fn record(
    addr: SocketAddr,
    trust: &Trust,
    out: &std::path::Path,
    seconds: Option<f32>,
) -> Result<(), String> {
    use psao_proto::capture::CaptureWriter;
    let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut writer =
        CaptureWriter::new(std::io::BufWriter::new(file)).map_err(|e| e.to_string())?;
    let config = ClientConfig {
        capture: true,
        ..ClientConfig::default()
    };
    let h = connect(addr, trust, config, Duration::from_secs(10))
        .await
        .map_err(|e| e.to_string())?;
    let start = Instant::now();
    let until = seconds.map(|s| start + seconds_of(s));
    let (mut frames, mut bytes, mut dropped) = (0u64, 0u64, 0u64);
    let mut drain = |writer: &mut CaptureWriter<_>| -> Result<(), String> {
        let (got, lost) = h.take_captured();
        dropped += lost;
        for (at, f) in got {
            let t = at.saturating_duration_since(start).as_micros() as u64;
            writer.write(t, &f).map_err(|e| e.to_string())?;
            frames += 1;
            bytes += f.len() as u64;
        }
        Ok(())
    };
    loop {
        tokio::time::sleep(Duration::from_millis(50)).await;
        drain(&mut writer)?;
        let ended = h.ended() != Ended::Running;
        if ended || until.is_some_and(|u| Instant::now() >= u) {
            break;
        }
    }
    // Frames that came after the last look.
    drain(&mut writer)?;
    writer.finish().map_err(|e| e.to_string())?;
    h.close().await;
    println!(
        "recorded {frames} frames ({bytes} bytes) in {:.1} s to {}{}",
        start.elapsed().as_secs_f64(),
        out.display(),
        if dropped > 0 {
            format!("; {dropped} frames dropped (the writer fell behind)")
        } else {
            String::new()
        }
    );
    Ok(())
}

fn inspect(path: &std::path::Path, quiet: bool) -> Result<(), String> {
    use psao_codec::{Decoder, Event, FrameHeader};
    use psao_proto::capture::CaptureReader;
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let limits = Limits::default();
    let reader = CaptureReader::new(std::io::BufReader::new(file), limits.max_frame_bytes)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let mut decoder = Decoder::new(limits);
    let (mut n, mut keyframes, mut bytes, mut failed) = (0u64, 0u64, 0u64, 0u64);
    let mut last_time = 0;
    for record in reader {
        let r = record.map_err(|e| format!("{}: {e}", path.display()))?;
        n += 1;
        bytes += r.frame.len() as u64;
        last_time = r.time_us;
        let header = FrameHeader::parse(&r.frame);
        let outcome = match decoder.receive(&r.frame) {
            Ok(Event::Applied { sequence, keyframe }) => {
                keyframes += keyframe as u64;
                format!("applied, mirror at {sequence}")
            }
            Ok(Event::Stale { .. }) => "stale".to_string(),
            Ok(Event::NeedKeyframe { have, .. }) => {
                format!("needs a keyframe (mirror at {have:?})")
            }
            Err(e) => {
                failed += 1;
                format!("error: {e}")
            }
        };
        if !quiet {
            match header {
                Ok(h) => println!(
                    "#{n:<6} {:9.3} ms {:7} bytes  {} seq {:<6} base {:<6} {:?} {} messages  -> {outcome}",
                    r.time_us as f64 / 1e3,
                    r.frame.len(),
                    if h.keyframe { "keyframe" } else { "delta   " },
                    h.sequence,
                    h.base_sequence,
                    h.compression,
                    h.message_count,
                ),
                Err(e) => println!(
                    "#{n:<6} {:9.3} ms {:7} bytes  bad header: {e}",
                    r.time_us as f64 / 1e3,
                    r.frame.len()
                ),
            }
        }
    }
    let instances = decoder.mirror().instances().count();
    println!(
        "{}: {n} frames ({keyframes} keyframes, {failed} failed), {bytes} bytes over {:.3} s; mirror at sequence {:?} with {instances} instances",
        path.display(),
        last_time as f64 / 1e6,
        decoder.mirror().sequence()
    );
    Ok(())
}

fn pipeline_config(density: f32, rays: u32) -> PipelineConfig {
    PipelineConfig {
        density,
        ao: AoParams {
            rays,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    }
}

fn load_scene(path: Option<&std::path::Path>) -> Result<(Scene, String), String> {
    match path {
        None => Ok((default_scene(), "default".into())),
        Some(p) => {
            let scene = load_gltf(p).map_err(|e| e.to_string())?;
            let name = p
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            Ok((scene, name))
        }
    }
}

fn read_roots(
    path: &std::path::Path,
) -> Result<Vec<rustls::pki_types::CertificateDer<'static>>, String> {
    use rustls::pki_types::pem::PemObject;
    rustls::pki_types::CertificateDer::pem_file_iter(path)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .map_err(|e| format!("{}: {e}", path.display()))
}

/// One status line: server rate, bit rate per client, work per frame.
fn status(s: &ServerStats, prev: &ServerStats, dt: f64) -> String {
    let frames = (s.frames - prev.frames).max(1) as f64;
    let clients = s.clients.max(1) as f64;
    format!(
        "{:5.1} fps | {:6.3} Mbit/s per client | traced {:5.0}/frame | sent {:4.0}/frame | step {:5.2} ms | frame age {:5.1} ms | {} clients",
        (s.frames - prev.frames) as f64 / dt,
        (s.written_bytes - prev.written_bytes) as f64 * 8.0 / dt / 1e6 / clients,
        (s.report.traced - prev.report.traced) as f64 / frames,
        (s.report.updated - prev.report.updated) as f64 / frames,
        (s.step_time - prev.step_time).as_secs_f64() * 1e3 / frames,
        s.frame_age * 1e3,
        s.clients,
    )
}

async fn demo(
    seconds: f32,
    rate: u16,
    clients: usize,
    density: f32,
    rays: u32,
    mut shots: Shots,
    cull: bool,
) -> Result<(), String> {
    if !(seconds > 0.0 && seconds <= 3600.0) {
        return Err("--seconds must be in (0, 3600]".into());
    }
    let identity = Identity::self_signed().map_err(|e| e.to_string())?;
    let config = ServerConfig {
        frame_rate: rate,
        pipeline: PipelineConfig {
            cull: cull.then(ViewerCull::default),
            ..pipeline_config(density, rays)
        },
        ..ServerConfig::default()
    };
    println!("psao demo: preparing the default scene (points, grids, first trace)...");
    let t = Instant::now();
    let server = serve(default_scene(), config, &identity)
        .await
        .map_err(|e| e.to_string())?;
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
        .await
        .map_err(|e| e.to_string())?;
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
            let line = shots.take(mirror, t).await?;
            bar.println(line);
        }
        if frames >= total {
            break;
        }
        if handles.iter().any(|h| h.ended() != Ended::Running) {
            bar.abandon();
            return Err("a client's session ended early".into());
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
struct Shots {
    count: u32,
    taken: u32,
    out: PathBuf,
    scene: Arc<Scene>,
}

/// Size of the demo's images.
const SHOT_SIZE: (u32, u32) = (480, 270);

impl Shots {
    /// `count` images into `out` (created now, so a bad path fails early).
    fn new(count: u32, out: PathBuf) -> Result<Shots, String> {
        if count > 0 {
            std::fs::create_dir_all(&out)
                .map_err(|e| format!("cannot create {}: {e}", out.display()))?;
        }
        Ok(Shots {
            count,
            taken: 0,
            out,
            scene: Arc::new(default_scene()),
        })
    }

    /// Whether the next image is due after `frames` of `total`: images
    /// fall at the ends of `count` equal parts of the run.
    fn due(&self, frames: u64, total: u64) -> bool {
        self.taken < self.count && frames * self.count as u64 >= total * (self.taken as u64 + 1)
    }

    /// Renders and writes the image at scene time `t` from `mirror`;
    /// returns a line saying where it went.
    async fn take(&mut self, mirror: psao_codec::Mirror, t: f32) -> Result<String, String> {
        self.taken += 1;
        let (scene, out, k) = (self.scene.clone(), self.out.clone(), self.taken);
        tokio::task::spawn_blocking(move || -> Result<String, String> {
            let path = scene
                .camera
                .as_ref()
                .ok_or("the scene has no camera path")?;
            let view =
                View::new(path.at(t), SHOT_SIZE.0, SHOT_SIZE.1).map_err(|e| e.to_string())?;
            let posed = PosedScene::new(&scene, t).map_err(|e| e.to_string())?;
            let g = posed.gbuffer(&view);
            let image = psao_image(&mirror, &g).map_err(|e| e.to_string())?;
            let ao = out.join(format!("demo-{k:02}-ao.png"));
            bench::images::ao_png16(&image.ao, view.width, view.height)
                .save(&ao)
                .map_err(|e| format!("{}: {e}", ao.display()))?;
            let lit = out.join(format!("demo-{k:02}-lit.png"));
            image::RgbImage::from_raw(
                view.width,
                view.height,
                bench::images::composite(&g, &image.ao),
            )
            .ok_or("image size")?
            .save(&lit)
            .map_err(|e| format!("{}: {e}", lit.display()))?;
            Ok(format!(
                "image {k}: t = {t:.2} s, AO from the client's mirror (sequence {}) -> {} and {}",
                mirror.sequence().map_or("none".into(), |s| s.to_string()),
                ao.display(),
                lit.display()
            ))
        })
        .await
        .map_err(|e| format!("image task: {e}"))?
    }
}

/// CPU seconds this process has used (user + system), where /proc tells.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces), from field 3.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Stops the server, waits for the clients to apply its last frame,
/// checks their mirrors against its tables and prints the figures.
async fn summarize(
    server: ServerHandle,
    handles: Vec<ClientHandle>,
    start: ServerStats,
    wall: f64,
    cpu: Option<f64>,
) -> Result<(), String> {
    let (pipeline, end) = server
        .shutdown(Duration::from_secs(2))
        .await
        .map_err(|e| e.to_string())?;
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
            "  client {k}            {} frames applied ({} keyframes), {} failed, {} stale, {} keyframe requests, {:.1} kB received",
            s.applied,
            s.keyframes,
            s.failed,
            s.stale,
            s.requests,
            s.bytes as f64 / 1e3
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
        Err("a client's mirror differs from the server".into())
    }
}

async fn serve_until_stopped(
    scene: Scene,
    config: ServerConfig,
    identity: &Identity,
    seconds: Option<f32>,
) -> Result<(), String> {
    let server = serve(scene, config, identity)
        .await
        .map_err(|e| e.to_string())?;
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
    let until = seconds.map(|s| Instant::now() + seconds_of(s));
    let mut prev = (server.stats(), Instant::now());
    loop {
        tokio::select! {
            _ = tokio::signal::ctrl_c() => break,
            _ = tokio::time::sleep(Duration::from_secs(1)) => {
                let s = server.stats();
                println!("{}", status(&s, &prev.0, prev.1.elapsed().as_secs_f64()));
                prev = (s, Instant::now());
                if until.is_some_and(|u| Instant::now() >= u) {
                    break;
                }
            }
        }
    }
    println!("shutting down");
    server
        .shutdown(Duration::from_secs(2))
        .await
        .map_err(|e| e.to_string())?;
    Ok(())
}

async fn view(addr: SocketAddr, trust: &Trust, seconds: Option<f32>) -> Result<(), String> {
    let h = connect(
        addr,
        trust,
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await
    .map_err(|e| e.to_string())?;
    if let Some(w) = h.with_session(|s| s.welcome().cloned()) {
        println!(
            "connected to {addr}: scene `{}`, {} Hz, compression {}, frames up to {} bytes",
            w.scene, w.frame_rate, w.compression, w.max_frame_bytes
        );
    }
    let until = seconds.map(|s| Instant::now() + seconds_of(s));
    let mut prev = (h.with_session(|s| s.stats()), Instant::now());
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let (s, seq) = h.with_session(|s| {
            while s.poll_event().is_some() {}
            (s.stats(), s.mirror().sequence())
        });
        let dt = prev.1.elapsed().as_secs_f64();
        println!(
            "{:5.1} frames/s | {:6.3} Mbit/s | sequence {:?} | {} keyframes, {} failed, rtt {:.1} ms",
            (s.applied - prev.0.applied) as f64 / dt,
            (s.bytes - prev.0.bytes) as f64 * 8.0 / dt / 1e6,
            seq,
            s.keyframes,
            s.failed,
            h.rtt().as_secs_f64() * 1e3
        );
        prev = (s, Instant::now());
        if let Ended::Closed(c) = h.ended() {
            println!("session ended: {c}");
            return Ok(());
        }
        if until.is_some_and(|u| Instant::now() >= u) {
            break;
        }
    }
    h.close().await;
    Ok(())
}
