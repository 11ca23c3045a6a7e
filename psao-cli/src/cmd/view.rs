//! `psao view`: a headless client that keeps a mirror in sync and prints
//! figures once a second.

use std::time::{Duration, Instant};

use psao_proto::control::NoticeCode;
use psao_proto::{ClientConfig, ClientEvent, Ended, connect};

use super::common::{ServerArgs, human_bytes, seconds_of};

/// Arguments of `psao view`.
#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    server: ServerArgs,
    /// Follow a MoQ broadcast through a relay instead of connecting to a
    /// server: `https://HOST:PORT/BROADCAST` (spec/moq.md). Repeat it to
    /// name relays to fall back on, tried in order (they must share the
    /// certificate --fingerprint or --ca checks).
    #[arg(long, value_name = "URL", conflicts_with = "connect")]
    subscribe: Vec<String>,
    /// With --subscribe: this many subscribers in one process (a load
    /// generator), subscriber k starting at relay k of the list.
    #[arg(long, default_value_t = 1, requires = "subscribe", value_parser = clap::value_parser!(u16).range(1..=10000))]
    subscribers: u16,
}

/// Connects and prints a line a second until the session ends or
/// `--seconds` pass.
pub async fn run(args: Args) -> anyhow::Result<()> {
    if !args.subscribe.is_empty() {
        return super::relay::view(&args.subscribe, &args.server, args.subscribers.into()).await;
    }
    let trust = args.server.trust()?;
    let addr = args.server.addr()?;
    let connecting = Instant::now();
    let h = connect(
        addr,
        &trust,
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await?;
    if let Some(w) = h.with_session(|s| s.welcome().cloned()) {
        let compression = match w.compression {
            0 => "none",
            1 => "LZ4",
            2 => "zstd",
            _ => "unknown",
        };
        println!(
            "connected to {addr}: scene `{}`, {} Hz, {compression} compression, frames up to {}",
            w.scene,
            w.frame_rate,
            human_bytes(w.max_frame_bytes as u64)
        );
    }
    // Connect to the first keyframe applied (as `--subscribe` reports it).
    let joined = h
        .wait_for(Duration::from_secs(10), |s| s.mirror().sequence().is_some())
        .await
        .then(|| connecting.elapsed());
    let started = Instant::now();
    let until = args.server.seconds.map(|s| Instant::now() + seconds_of(s));
    let mut prev = (h.with_session(|s| s.stats()), Instant::now());
    let ended = loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let (s, seq, notices) = h.with_session(|s| {
            let mut notices = Vec::new();
            while let Some(e) = s.poll_event() {
                if let ClientEvent::Notice { code, text } = e {
                    notices.push((code, text));
                }
            }
            (s.stats(), s.mirror().sequence(), notices)
        });
        // The server's notices, as it words them.
        for (code, text) in notices {
            let what = match code {
                NoticeCode::BelowRate => "the server runs below its announced rate",
                NoticeCode::FellBehind => "fell behind; a keyframe follows",
                NoticeCode::EventRefused => "a scene event was refused",
                _ => "notice",
            };
            // The server's text is shown escaped: it may hold control
            // characters (a terminal would obey escape sequences).
            println!("server notice: {what}: {}", text.escape_debug());
        }
        let dt = prev.1.elapsed().as_secs_f64();
        let applied = s.applied - prev.0.applied;
        // A still scene sends no frames: in sync, not stalled.
        let rate = match (applied, seq) {
            (0, Some(_)) if s.requests == prev.0.requests => "in sync, scene static".to_string(),
            (0, None) => "waiting for the first keyframe".to_string(),
            _ => format!("{:5.1} frames/s", applied as f64 / dt),
        };
        let sequence = seq.map_or("none".to_string(), |q| q.to_string());
        println!(
            "{rate} | {:6.3} Mbit/s | mirror at frame {sequence} | {} keyframes, {} failed | rtt {:.1} ms",
            (s.bytes - prev.0.bytes) as f64 * 8.0 / dt / 1e6,
            s.keyframes,
            s.failed,
            h.rtt().as_secs_f64() * 1e3
        );
        prev = (s, Instant::now());
        if let Ended::Closed(c) = h.ended() {
            break Some(c);
        }
        if until.is_some_and(|u| Instant::now() >= u) {
            break None;
        }
    };
    let (s, seq, instances, mirror) = h.with_session(|s| {
        let m = s.mirror();
        (s.stats(), m.sequence(), m.instances().count(), m.bytes())
    });
    if ended.is_none() {
        h.close().await;
    }
    let secs = started.elapsed().as_secs_f64();
    println!("summary over {secs:.1} s:");
    println!(
        "  frames     {} applied ({} keyframes), {} failed, {} stale, {} keyframe requests",
        s.applied, s.keyframes, s.failed, s.stale, s.requests
    );
    println!(
        "  received   {} ({:.3} Mbit/s)",
        human_bytes(s.bytes),
        s.bytes as f64 * 8.0 / secs.max(1e-9) / 1e6
    );
    println!(
        "  joined     {}",
        joined.map_or("no keyframe within 10 s".to_string(), |t| format!(
            "{:.0} ms after connecting",
            t.as_secs_f64() * 1e3
        ))
    );
    println!(
        "  mirror     {instances} instances, {}, at frame {}",
        human_bytes(mirror),
        seq.map_or("none".to_string(), |q| q.to_string())
    );
    match ended {
        Some(c) => println!("  ended      {c}"),
        None => println!("  ended      closed here after --seconds"),
    }
    Ok(())
}
