//! `psao view`: a headless client that keeps a mirror in sync and prints
//! figures once a second.

use std::time::{Duration, Instant};

use psao_proto::{ClientConfig, Ended, connect};

use super::common::{ServerArgs, seconds_of};

/// Arguments of `psao view`.
#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    server: ServerArgs,
}

/// Connects and prints a line a second until the session ends or
/// `--seconds` pass.
pub async fn run(args: Args) -> anyhow::Result<()> {
    let trust = args.server.trust()?;
    let addr = args.server.connect;
    let h = connect(
        addr,
        &trust,
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await?;
    if let Some(w) = h.with_session(|s| s.welcome().cloned()) {
        println!(
            "connected to {addr}: scene `{}`, {} Hz, compression {}, frames up to {} bytes",
            w.scene, w.frame_rate, w.compression, w.max_frame_bytes
        );
    }
    let until = args.server.seconds.map(|s| Instant::now() + seconds_of(s));
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
