//! PSAO through a Media over QUIC relay (spec/moq.md): `--publish` for
//! `psao serve`, and `--subscribe` for `psao view` and `psao record`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use psao_codec::Limits;
use psao_moq::GroupPolicy;
use psao_moq::net::{PublishOptions, RelayUrl, SubscribeOptions, Subscription, subscribe};
use psao_proto::Trust;
use psao_proto::capture::CaptureWriter;
use psao_proto::tls::parse_fingerprint;

use super::common::{ServerArgs, human_bytes, read_roots, seconds_of};

/// Publishing to a relay, for `psao serve`.
#[derive(clap::Args, Clone, Debug)]
pub struct PublishArgs {
    /// Also publish the scene as a MoQ broadcast to this relay
    /// (`https://HOST:PORT/`, a moq-relay), for any number of viewers
    /// (spec/moq.md); direct clients are served as well.
    #[arg(long, value_name = "URL")]
    pub publish: Option<String>,
    /// The broadcast's name [default: psao/SCENE].
    #[arg(long, requires = "publish")]
    pub broadcast: Option<String>,
    /// SHA-256 fingerprint of the relay's certificate (moq-relay serves it
    /// at http://HOST:PORT/certificate.sha256); this or --relay-ca.
    #[arg(long, requires = "publish", conflicts_with = "relay_ca")]
    pub relay_fingerprint: Option<String>,
    /// PEM file of roots the relay's certificate must chain to (for the
    /// URL's host).
    #[arg(long, requires = "publish")]
    pub relay_ca: Option<PathBuf>,
    /// A new group, opening with a keyframe, at least this often, seconds
    /// (the longest a late joiner waits; spec/moq.md 4, `T`).
    #[arg(long, default_value_t = 2.0)]
    pub group_seconds: f32,
    /// A new group once the deltas of one pass this many times its
    /// keyframe's bytes (spec/moq.md 4, `R`).
    #[arg(long, default_value_t = 1.0)]
    pub group_ratio: f64,
}

/// How to trust a relay: a pinned fingerprint or PEM roots for `host`.
pub fn relay_trust(
    fingerprint: Option<&str>,
    ca: Option<&Path>,
    host: &str,
) -> anyhow::Result<Trust> {
    match (fingerprint, ca) {
        (Some(f), _) => Ok(Trust::Fingerprint(parse_fingerprint(f)?)),
        (None, Some(ca)) => Ok(Trust::Roots {
            roots: read_roots(ca)?,
            name: host.to_string(),
        }),
        (None, None) => bail!(
            "give the relay's certificate fingerprint (moq-relay serves it at http://HOST:PORT/certificate.sha256) or a PEM file of roots"
        ),
    }
}

impl PublishArgs {
    /// The publication `--publish` asks for (`None` without it).
    pub fn options(
        &self,
        scene: &str,
        rate: u16,
        digest_every: u16,
    ) -> anyhow::Result<Option<PublishOptions>> {
        let Some(url) = &self.publish else {
            return Ok(None);
        };
        let relay: RelayUrl = url.parse()?;
        if !(self.group_seconds.is_finite() && self.group_seconds > 0.0) {
            bail!("--group-seconds must be above 0");
        }
        if !(self.group_ratio.is_finite() && self.group_ratio > 0.0) {
            bail!("--group-ratio must be above 0");
        }
        let trust = relay_trust(
            self.relay_fingerprint.as_deref(),
            self.relay_ca.as_deref(),
            &relay.host,
        )
        .context("--publish: --relay-fingerprint or --relay-ca")?;
        Ok(Some(PublishOptions {
            relay,
            trust,
            broadcast: self.broadcast.clone(),
            scene: scene.to_string(),
            frame_rate: rate,
            policy: GroupPolicy {
                delta_ratio: self.group_ratio,
                max_age: seconds_of(self.group_seconds),
                digest_every: digest_every.into(),
            },
        }))
    }
}

/// The subscription `--subscribe URL...` asks for, trusting the relays as
/// --fingerprint or --ca say; subscriber `k` of several starts at relay
/// `k` of the list (modulo its length) and falls back on the others in
/// turn.
fn subscription(
    urls: &[String],
    server: &ServerArgs,
    capture: bool,
    k: usize,
) -> anyhow::Result<Subscription> {
    let mut relays = urls
        .iter()
        .map(|u| u.parse::<RelayUrl>())
        .collect::<Result<Vec<_>, _>>()?;
    let n = relays.len();
    relays.rotate_left(k % n);
    let trust = relay_trust(
        server.fingerprint.as_deref(),
        server.ca.as_deref(),
        &relays[0].host,
    )
    .context("--subscribe: --fingerprint or --ca")?;
    Ok(subscribe(SubscribeOptions {
        relays,
        trust,
        limits: Limits::default(),
        digests: true,
        capture,
    })?)
}

/// Durations in seconds as their median, lowest and highest, in ms
/// (sorts them).
pub fn spread_ms(v: &mut [f64]) -> String {
    if v.is_empty() {
        return "none".into();
    }
    v.sort_by(f64::total_cmp);
    format!(
        "{:.0} ms median, {:.0}-{:.0} ms",
        v[v.len() / 2] * 1e3,
        v[0] * 1e3,
        v[v.len() - 1] * 1e3
    )
}

/// `psao view --subscribe`: follows the broadcast with `count` subscribers
/// (a load generator past 1), a line a second, and a summary.
pub async fn view(urls: &[String], server: &ServerArgs, count: usize) -> anyhow::Result<()> {
    let subs = (0..count)
        .map(|k| subscription(urls, server, false, k))
        .collect::<anyhow::Result<Vec<_>>>()?;
    println!(
        "{count} subscriber(s) to {} ({} relay(s), tried in turn)",
        urls[0],
        urls.len()
    );
    let started = Instant::now();
    let until = server.seconds.map(|s| Instant::now() + seconds_of(s));
    let mut printed_catalog = false;
    let sum = |subs: &[Subscription]| {
        subs.iter().fold((0u64, 0u64), |(a, b), s| {
            let st = s.stats();
            (a + st.follow.applied, b + st.follow.bytes)
        })
    };
    let mut prev = (sum(&subs), Instant::now());
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        if let Some(why) = subs.iter().find_map(|s| s.failed()) {
            bail!("cannot follow the broadcast: {why}");
        }
        if !printed_catalog && let Some(w) = subs[0].with_follower(|f| f.catalog().cloned()) {
            println!(
                "broadcast of scene `{}`: {} Hz, compression {}, frames up to {}, digests {}",
                w.scene,
                w.frame_rate,
                w.compression,
                human_bytes(w.max_frame_bytes.into()),
                if w.digest { "on" } else { "off" }
            );
            printed_catalog = true;
        }
        let now = sum(&subs);
        let dt = prev.1.elapsed().as_secs_f64();
        let n = count as f64;
        let s = subs[0].stats();
        let seq = subs[0].with_follower(|f| f.mirror().sequence());
        let in_sync = subs.iter().filter(|s| s.in_sync()).count();
        let missed: u64 = subs.iter().map(|s| s.stats().follow.groups_missed).sum();
        let wrong: u64 = subs
            .iter()
            .map(|s| s.stats().follow.digest_mismatches)
            .sum();
        println!(
            "{:5.1} frames/s | {:6.3} Mbit/s | mirror at frame {} | {in_sync}/{count} in sync | groups {} ({missed} missed) | digests {} ok, {wrong} wrong | relay {} ({} sessions){}",
            (now.0 - prev.0.0) as f64 / dt / n,
            (now.1 - prev.0.1) as f64 * 8.0 / dt / 1e6 / n,
            seq.map_or("none".to_string(), |q| q.to_string()),
            s.follow.groups,
            s.follow.digests_matched,
            s.relay,
            s.connects,
            s.last_error
                .as_ref()
                .map_or(String::new(), |e| format!(" | last: {e}")),
        );
        prev = (now, Instant::now());
        if until.is_some_and(|u| Instant::now() >= u) {
            break;
        }
    }
    let secs = started.elapsed().as_secs_f64();
    let stats: Vec<_> = subs.iter().map(|s| s.stats()).collect();
    let total = |f: fn(&psao_moq::net::SubscribeStats) -> u64| stats.iter().map(f).sum::<u64>();
    let mut joins: Vec<f64> = stats
        .iter()
        .filter_map(|s| s.join_time.map(|t| t.as_secs_f64()))
        .collect();
    let n = count as f64;
    println!("summary over {secs:.1} s ({count} subscriber(s); per subscriber where it says so):");
    println!(
        "  frames     {:.0} applied ({:.1} keyframes), {:.1} ignored, {:.1} broken per subscriber",
        total(|s| s.follow.applied) as f64 / n,
        total(|s| s.follow.keyframes) as f64 / n,
        total(|s| s.follow.ignored) as f64 / n,
        total(|s| s.follow.broken) as f64 / n
    );
    println!(
        "  received   {} per subscriber ({:.3} Mbit/s)",
        human_bytes(total(|s| s.follow.bytes) / count as u64),
        total(|s| s.follow.bytes) as f64 * 8.0 / secs.max(1e-9) / 1e6 / n
    );
    println!(
        "  joined     {} of {count}: {} after subscribing",
        joins.len(),
        spread_ms(&mut joins)
    );
    println!(
        "  in sync    {} of {count} at the end",
        subs.iter().filter(|s| s.in_sync()).count()
    );
    println!(
        "  digests    {} matched, {} did not; {} restarts, {} sessions",
        total(|s| s.follow.digests_matched),
        total(|s| s.follow.digest_mismatches),
        total(|s| s.restarts),
        total(|s| s.connects)
    );
    Ok(())
}

/// `psao record --subscribe`: writes every frame received to a capture
/// file until `--seconds`.
pub async fn record(urls: &[String], server: &ServerArgs, out: &Path) -> anyhow::Result<()> {
    let Some(seconds) = server.seconds else {
        bail!(
            "--subscribe needs --seconds with record (a broadcast has no end of its own to wait for)"
        );
    };
    let file = std::fs::File::create(out).with_context(|| out.display().to_string())?;
    let mut writer = CaptureWriter::new(std::io::BufWriter::new(file))?;
    let sub = subscription(urls, server, true, 0)?;
    let start = Instant::now();
    let until = start + seconds_of(seconds);
    let (mut frames, mut bytes, mut dropped) = (0u64, 0u64, 0u64);
    loop {
        tokio::time::sleep(Duration::from_millis(50)).await;
        if let Some(why) = sub.failed() {
            bail!("cannot follow the broadcast: {why}");
        }
        let (got, lost) = sub.take_captured();
        dropped += lost;
        for (at, f) in got {
            writer.write(at.saturating_duration_since(start).as_micros() as u64, &f)?;
            frames += 1;
            bytes += f.len() as u64;
        }
        if Instant::now() >= until {
            break;
        }
    }
    writer.finish()?;
    println!(
        "{}",
        super::common::recorded(frames, bytes, dropped, start, out)
    );
    Ok(())
}
