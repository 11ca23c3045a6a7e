//! `psao demo --relay`: the demo's server publishing its broadcast to two
//! clustered `moq-relay` processes on loopback, and the clients
//! subscribing through them (half through each), so that a newcomer sees
//! the fan-out work: the same live line, then a summary that checks every
//! subscriber's mirror against the server's tables.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use psao_codec::Limits;
use psao_moq::GroupPolicy;
use psao_moq::net::{
    LocalRelay, PublishOptions, RelayCert, SubscribeOptions, Subscription, find_relay_binary,
    publish_alongside, subscribe,
};
use psao_proto::{Identity, ServerConfig, Trust, serve};
use psao_scene::Pipeline;

use super::common::{cpu_seconds, human_bytes, status};
use super::relay::spread_ms;
use super::shots::Shots;

/// What `psao demo --relay` runs.
pub struct RelayDemo {
    /// Seconds to stream.
    pub seconds: f32,
    /// Frames per second.
    pub rate: u16,
    /// Subscribers, half through each relay.
    pub clients: usize,
    /// A digest every this many frames on the digest track.
    pub digest_interval: u16,
    /// The images the first subscriber renders.
    pub shots: Shots,
    /// The scene time the frames are posed ahead by.
    pub lead: f32,
    /// The relay binary (default: found on the PATH).
    pub relay_bin: Option<PathBuf>,
}

/// Runs it.
pub async fn run(d: RelayDemo, pipeline: Pipeline) -> anyhow::Result<()> {
    let RelayDemo {
        seconds,
        rate,
        clients,
        digest_interval,
        mut shots,
        lead,
        relay_bin,
    } = d;
    let bin = relay_bin.or_else(find_relay_binary).context(
        "psao demo --relay needs moq-relay: install it with `cargo install moq-relay --version 0.17.10 \
         --no-default-features --features noq`, or give --relay-bin",
    )?;
    let dir = std::env::temp_dir().join(format!("psao-demo-relay-{}", std::process::id()));
    let cert = RelayCert::generate(&dir)?;
    let a = LocalRelay::start(&bin, &cert, None, dir.join("relay-a.log"))?;
    let b = LocalRelay::start(&bin, &cert, Some(&a), dir.join("relay-b.log"))?;
    println!(
        "relays on 127.0.0.1:{} and 127.0.0.1:{} (the second dials the first; logs in {})",
        a.port,
        b.port,
        dir.display()
    );
    let options = PublishOptions {
        relay: a.url("").parse()?,
        trust: Trust::Fingerprint(cert.fingerprint),
        broadcast: None,
        scene: "default".into(),
        frame_rate: rate,
        policy: GroupPolicy {
            digest_every: digest_interval.into(),
            ..GroupPolicy::default()
        },
    };
    let (publishing, link) = publish_alongside(pipeline, &options).await?;
    let config = ServerConfig {
        bind: "127.0.0.1:0".parse()?,
        frame_rate: rate,
        digest_interval,
        scene_name: "default".into(),
        ..ServerConfig::default()
    };
    let server = serve(publishing, config, &Identity::self_signed()?).await?;
    println!(
        "server on {} publishing broadcast {} to relay a; {clients} subscribers, half through each relay",
        server.local_addr(),
        link.broadcast()
    );
    let subs: Vec<Subscription> = (0..clients)
        .map(|k| {
            let (first, second) = if k % 2 == 0 { (&a, &b) } else { (&b, &a) };
            subscribe(SubscribeOptions {
                relays: vec![
                    first.url(link.broadcast()).parse()?,
                    second.url(link.broadcast()).parse()?,
                ],
                trust: Trust::Fingerprint(cert.fingerprint),
                limits: Limits::default(),
                digests: true,
                capture: false,
            })
            .map_err(anyhow::Error::from)
        })
        .collect::<anyhow::Result<_>>()?;
    // The timed run starts once every subscriber has joined (applied a
    // keyframe): one that subscribes through the second relay after the
    // group began gets that group from where the relays' link picks it up
    // and waits for the next keyframe (spec/moq.md 4), up to
    // --group-seconds.
    let joined = Instant::now();
    while !subs.iter().all(|x| x.stats().join_time.is_some()) {
        if joined.elapsed() > Duration::from_secs(30) {
            bail!("not every subscriber joined within 30 s");
        }
        for x in &subs {
            if let Some(why) = x.failed() {
                bail!("a subscriber stopped: {why}");
            }
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let total = (seconds * rate as f32).round() as u64;
    let start = server.stats();
    let (started, cpu0) = (Instant::now(), cpu_seconds());
    let mut prev = (start.clone(), Instant::now(), 0u64);
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let s = server.stats();
        let dt = prev.1.elapsed().as_secs_f64();
        let bytes: u64 = subs.iter().map(|x| x.stats().follow.bytes).sum();
        let synced = subs.iter().filter(|x| x.in_sync()).count();
        println!(
            "{} | {synced}/{clients} subscribers in sync, {:.3} Mbit/s each",
            status(&s, &prev.0, dt),
            (bytes - prev.2) as f64 * 8.0 / dt / 1e6 / clients.max(1) as f64
        );
        for x in &subs {
            if let Some(why) = x.failed() {
                bail!("a subscriber stopped: {why}");
            }
        }
        let frames = s.frames - start.frames;
        let t = s.frames as f32 / rate as f32;
        while shots.due(frames, total) {
            let mirror = subs[0].with_follower(|f| f.mirror().clone());
            println!("{}", shots.take(mirror, t + lead).await?);
        }
        prev = (s, Instant::now(), bytes);
        if frames >= total {
            break;
        }
    }
    let wall = started.elapsed().as_secs_f64();
    let cpu = cpu_seconds().zip(cpu0).map(|(x, y)| x - y);
    let (publishing, end) = server.shutdown(Duration::from_secs(2)).await?;
    let link_stats = link.stats();
    let mut pipeline = publishing.into_inner();
    // The tracks are finished: the broadcast ends cleanly below.
    let last = psao_proto::FrameSource::keyframe(&mut pipeline)
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .sequence;
    // Each subscriber's mirror is compared as soon as it reaches the last
    // state (the broadcast has ended: a subscriber then subscribes again,
    // which starts a fresh mirror).
    let same = |x: &Subscription| {
        x.with_follower(|f| {
            (f.mirror().sequence() == Some(last)).then(|| {
                (0..pipeline.instance_count()).all(|i| {
                    let t = pipeline.table(i).expect("instance");
                    f.mirror()
                        .instance(i as u32)
                        .is_some_and(|m| m.words() == t.words() && m.buckets() == t.buckets())
                })
            })
        })
    };
    let mut compared: Vec<Option<bool>> = vec![None; subs.len()];
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until && compared.iter().any(Option::is_none) {
        for (c, x) in compared.iter_mut().zip(&subs) {
            if c.is_none() {
                *c = same(x);
            }
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let in_sync = compared.iter().filter(|c| **c == Some(true)).count();
    let stats: Vec<_> = subs.iter().map(|x| x.stats()).collect();
    let mut joins: Vec<f64> = stats
        .iter()
        .filter_map(|s| s.join_time.map(|t| t.as_secs_f64()))
        .collect();
    let received: u64 = stats.iter().map(|s| s.follow.bytes).sum();
    println!();
    println!("summary");
    println!(
        "  server frames       {} stepped in {wall:.2} s ({:.1} fps)",
        end.frames,
        (end.frames - start.frames) as f64 / wall
    );
    println!("{}", super::demo::schedule_line(&start, &end, rate));
    if let Some(cpu) = cpu {
        println!(
            "  process CPU         {cpu:.2} s over {wall:.2} s ({:.0}% of one core; server and {clients} subscribers together, relays apart)",
            100.0 * cpu / wall
        );
    }
    println!(
        "  broadcast           {} groups ({} by age, {} by bytes), {} deltas, {} written once to relay a ({} sessions)",
        link_stats.broadcast.groups,
        link_stats.broadcast.rolled_by_age,
        link_stats.broadcast.rolled_by_ratio,
        link_stats.broadcast.deltas,
        human_bytes(link_stats.broadcast.frame_bytes),
        link_stats.connects
    );
    println!(
        "  per subscriber      {:.3} Mbit/s received",
        received as f64 * 8.0 / wall / 1e6 / clients.max(1) as f64
    );
    println!(
        "  join                {} (subscribe to first keyframe applied)",
        spread_ms(&mut joins)
    );
    println!(
        "  digests             {} matched, {} differed",
        stats.iter().map(|s| s.follow.digests_matched).sum::<u64>(),
        stats
            .iter()
            .map(|s| s.follow.digest_mismatches)
            .sum::<u64>()
    );
    println!(
        "  mirrors             {in_sync} of {clients} equal to the server's tables at sequence {last}"
    );
    drop(subs);
    link.close().await;
    drop((b, a));
    let _ = std::fs::remove_dir_all(&dir);
    if in_sync == clients {
        Ok(())
    } else {
        Err(anyhow::anyhow!(
            "a subscriber's mirror differs from the server"
        ))
    }
}
