//! `psao record`: a client that writes every frame it receives to a
//! capture file (spec/capture.md).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context as _;
use psao_proto::capture::CaptureWriter;
use psao_proto::{ClientConfig, Ended, connect};

use super::common::{ServerArgs, recorded, seconds_of};

/// Arguments of `psao record`.
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
    /// The capture file to write.
    #[arg(long)]
    out: PathBuf,
}

/// Connects, records until the server closes or `--seconds` pass, and
/// says what it wrote.
pub async fn run(args: Args) -> anyhow::Result<()> {
    if !args.subscribe.is_empty() {
        return super::relay::record(&args.subscribe, &args.server, &args.out).await;
    }
    let trust = args.server.trust()?;
    let out = &args.out;
    let file = std::fs::File::create(out).with_context(|| out.display().to_string())?;
    let mut writer = CaptureWriter::new(std::io::BufWriter::new(file))?;
    let config = ClientConfig {
        capture: true,
        ..ClientConfig::default()
    };
    let h = connect(args.server.addr()?, &trust, config, Duration::from_secs(10)).await?;
    let start = Instant::now();
    let until = args.server.seconds.map(|s| start + seconds_of(s));
    let (mut frames, mut bytes, mut dropped) = (0u64, 0u64, 0u64);
    let mut drain = |writer: &mut CaptureWriter<_>| -> anyhow::Result<()> {
        let (got, lost) = h.take_captured();
        dropped += lost;
        for (at, f) in got {
            let t = at.saturating_duration_since(start).as_micros() as u64;
            writer.write(t, &f)?;
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
    writer.finish()?;
    h.close().await;
    println!("{}", recorded(frames, bytes, dropped, start, out));
    Ok(())
}
