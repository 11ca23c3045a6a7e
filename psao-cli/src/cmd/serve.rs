//! `psao serve`: the reference server for clients elsewhere, with a status
//! line a second, until Ctrl-C or `--seconds`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use psao_proto::tls::fingerprint_hex;
use psao_proto::{Identity, ServerConfig, serve};
use psao_scene::{Pipeline, PipelineConfig, ViewerCull};

use super::common::{load_scene, pipeline_config, seconds_of, status};

/// Arguments of `psao serve`.
#[derive(clap::Args)]
pub struct Args {
    /// A scene file: glTF (.gltf, .glb) or OBJ (default: the embedded default scene).
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
        scene_name: name,
        ..ServerConfig::default()
    };
    let pipeline = PipelineConfig {
        cull: args.cull.then(ViewerCull::default),
        ..pipeline_config(args.density, 64)
    };
    println!("preparing the scene (points, grids, first trace)...");
    let pipeline = Pipeline::new(scene, pipeline)?;
    let server = serve(pipeline, config, &identity).await?;
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
    let until = args.seconds.map(|s| Instant::now() + seconds_of(s));
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
    server.shutdown(Duration::from_secs(2)).await?;
    Ok(())
}
