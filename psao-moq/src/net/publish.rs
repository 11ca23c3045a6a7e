//! The publisher: plans groups with a [`Broadcaster`] over what a frame
//! source steps, and writes the broadcast's three tracks (spec/moq.md 2-5)
//! into a moq-net origin that a session to the relay publishes. The
//! session is re-established when the relay goes away; the broadcast and
//! its latest group live in the origin meanwhile.
//!
//! Two ways to drive it: [`publish()`] steps the source on a thread of its
//! own at the frame rate; [`publish_alongside()`] wraps the source in a
//! [`Publishing`] source that the reference QUIC server steps, so one
//! process serves direct clients and the broadcast from the same frames.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::Affine3A;
use moq_net::{Timestamp, broadcast, group, origin, track};
use psao_codec::EncodedFrame;
use psao_proto::control::{VERSION, Welcome};
use psao_proto::tls::Trust;
use psao_proto::{ClientViews, FrameSource, SourceError, SourceInfo, StepReport};
use tracing::{info, warn};

use super::dial::{MoqError, RelayUrl, dial};
use crate::broadcaster::{BroadcastStats, Broadcaster, GroupPolicy, Write};
use crate::catalog::{broadcast_name, encode_catalog, track as names};

/// What to publish where.
#[derive(Clone, Debug)]
pub struct PublishOptions {
    /// The relay (its path is not used).
    pub relay: RelayUrl,
    /// How the relay's certificate is checked.
    pub trust: Trust,
    /// The broadcast's name (default: [`broadcast_name`] of the scene).
    pub broadcast: Option<String>,
    /// The scene's name, for the catalog.
    pub scene: String,
    /// Frames per second the source is stepped at (1..=1000).
    pub frame_rate: u16,
    /// When groups roll over, and digests.
    pub policy: GroupPolicy,
}

/// What a publisher has done.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PublishStats {
    /// Groups, frames, bytes and digests written.
    pub broadcast: BroadcastStats,
    /// Ticks stepped.
    pub ticks: u64,
    /// Time spent stepping the source.
    pub step_time: Duration,
    /// What the steps did (summed).
    pub report: StepReport,
    /// Sessions established with the relay.
    pub connects: u64,
    /// Whether a session with the relay is up now.
    pub connected: bool,
    /// Writes the origin refused (logged).
    pub write_errors: u64,
    /// Steps of the source that failed.
    pub step_errors: u64,
    /// Why the last session with the relay ended, or the last dial failed.
    pub last_error: Option<String>,
}

/// The relay side of a publication: the origin, the broadcast and the
/// session kept up with the relay. Dropping it ends the broadcast.
pub struct Link {
    name: String,
    pool: moq_net::cache::Pool,
    stats: Arc<Mutex<PublishStats>>,
    task: tokio::task::JoinHandle<()>,
    close: Option<tokio::sync::oneshot::Sender<()>>,
    broadcast: broadcast::Producer,
    _catalog: track::Producer,
    _origin: origin::Producer,
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Link")
            .field("broadcast", &self.name)
            .finish()
    }
}

impl Link {
    /// The broadcast's name.
    pub fn broadcast(&self) -> &str {
        &self.name
    }

    /// What the publication has done so far.
    pub fn stats(&self) -> PublishStats {
        lock(&self.stats).clone()
    }

    /// Bytes of groups the origin holds now (its cache: the groups of the
    /// last few seconds, for the relay to fetch).
    pub fn cached_bytes(&self) -> u64 {
        self.pool.used()
    }

    /// Ends the broadcast cleanly: the catalog finished, the broadcast
    /// closed, and the session closed once the relay has what was written
    /// (at most 2 s). Finish the frames first (drop the [`Publishing`]
    /// source, or stop the [`Publisher`]) so that subscribers see the
    /// tracks end rather than fail.
    pub async fn close(mut self) {
        let _ = self._catalog.finish();
        self.broadcast.close();
        if let Some(tx) = self.close.take()
            && tx.send(()).is_ok()
        {
            let _ = tokio::time::timeout(Duration::from_secs(2), &mut self.task).await;
        }
    }
}

impl Drop for Link {
    /// Ends the broadcast and the session with the relay at once (see
    /// [`Link::close`] for a clean end).
    fn drop(&mut self) {
        let _ = self._catalog.finish();
        self.task.abort();
        self.broadcast.close();
    }
}

/// A frame source that publishes what it steps: each step goes to the
/// wrapped source, and its frame (or a keyframe, when a group starts) to
/// the broadcast; the step's frame is returned unchanged, so a server can
/// stream it to its own clients too.
pub struct Publishing<S> {
    inner: S,
    broadcaster: Broadcaster,
    tracks: Tracks,
    stats: Arc<Mutex<PublishStats>>,
}

impl<S> std::fmt::Debug for Publishing<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publishing")
            .field("broadcaster", &self.broadcaster)
            .finish()
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl<S> Publishing<S> {
    /// The wrapped source.
    pub fn inner(&self) -> &S {
        &self.inner
    }

    /// The wrapped source, after the last step (the tracks finished).
    pub fn into_inner(self) -> S {
        self.inner
    }
}

impl<S: FrameSource> FrameSource for Publishing<S> {
    fn info(&self) -> SourceInfo {
        self.inner.info()
    }

    fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, StepReport), SourceError> {
        let t0 = Instant::now();
        let (frame, report) = self.inner.step(dt)?;
        let step_time = t0.elapsed();
        let inner = &mut self.inner;
        let writes = match self
            .broadcaster
            .step(Instant::now(), frame.clone(), || inner.keyframe())
        {
            Ok(w) => w,
            Err(e) => {
                warn!("keyframe for the broadcast failed: {e}");
                Vec::new()
            }
        };
        let mut errors = 0;
        for w in writes {
            let frames = !matches!(w, Write::Digest { .. });
            if let Err(e) = self.tracks.write(w) {
                warn!("writing the broadcast: {e}");
                errors += 1;
                if frames {
                    // The group's later deltas would not apply for anyone:
                    // it ends with the frames it has, and the next step
                    // opens a new one.
                    self.broadcaster.interrupt();
                    if let Some(g) = self.tracks.open.take() {
                        let _ = g.finish();
                    }
                }
            }
        }
        let mut s = lock(&self.stats);
        s.ticks += 1;
        s.step_time += step_time;
        s.report.accumulate(&report);
        s.broadcast = self.broadcaster.stats();
        s.write_errors += errors;
        Ok((frame, report))
    }

    fn keyframe(&mut self) -> Result<EncodedFrame, SourceError> {
        self.inner.keyframe()
    }

    fn place(&mut self, instance: u32, transform: Affine3A) -> Result<(), SourceError> {
        self.inner.place(instance, transform)
    }

    fn set_views(&mut self, views: ClientViews<'_>) {
        self.inner.set_views(views)
    }
}

/// Connects a publishing session for `origin` to the relay.
async fn connect(
    url: &RelayUrl,
    trust: &Trust,
    origin: &origin::Producer,
) -> Result<moq_net::Session, MoqError> {
    let transport = dial(url, trust).await?;
    let client = moq_net::Client::new().with_publisher(origin);
    let (session, driver) = tokio::time::timeout(
        super::dial::SETUP_TIMEOUT,
        client.connect(Instant::now(), transport),
    )
    .await
    .map_err(|_| MoqError::Timeout("the MoQ setup with the relay"))??;
    tokio::spawn(moq_net::time::run(driver));
    Ok(session)
}

/// Sets up the broadcast of `source` on a relay and wraps the source in a
/// [`Publishing`] one, for a caller that steps it (the reference server).
/// Returns once the first session with the relay is up and the catalog is
/// written (an error otherwise). A source that culls to its viewers
/// cannot be published (a broadcast is the whole scene, spec/moq.md 6).
pub async fn publish_alongside<S: FrameSource>(
    source: S,
    options: &PublishOptions,
) -> Result<(Publishing<S>, Link), MoqError> {
    if !(1..=1000).contains(&options.frame_rate) {
        return Err(MoqError::Source(
            format!("frame rate {} is not in 1..=1000", options.frame_rate).into(),
        ));
    }
    let info = source.info();
    if info.culls {
        return Err(MoqError::Source(
            "a source that culls to its viewers cannot be published: a broadcast carries the whole scene"
                .into(),
        ));
    }
    let name = options
        .broadcast
        .clone()
        .unwrap_or_else(|| broadcast_name(&options.scene));
    let config = origin::Config::default();
    // The origin's groups are kept for the tracks' max age (5 s of media
    // time by default) whoever reads them: a slow subscriber at a relay
    // pins nothing here.
    let pool = config.pool.clone();
    let (origin, driver) = origin::Producer::new(config);
    tokio::spawn(moq_net::time::run(driver));
    let broadcast = origin.create_broadcast(name.as_str())?;
    let catalog = broadcast.create_track(names::CATALOG, None)?;
    let frames = broadcast.create_track(names::FRAMES, None)?;
    // The digest track only when the catalog says it is published.
    let digests = match options.policy.digest_every {
        0 => None,
        _ => Some(broadcast.create_track(names::DIGEST, None)?),
    };
    let welcome = Welcome {
        version: VERSION,
        compression: info.compression,
        point_format: info.point_format,
        max_frame_bytes: info.max_frame_bytes,
        max_payload_bytes: info.max_payload_bytes,
        frame_rate: options.frame_rate,
        culling: false,
        overflow: info.overflow,
        digest: options.policy.digest_every > 0,
        scene: options.scene.clone(),
    };
    let mut g = catalog.create_group(group::Info { sequence: 0 })?;
    g.write_frame(Timestamp::now(), encode_catalog(&welcome))?;
    g.finish()?;
    broadcast.announce(Default::default())?;

    let session = connect(&options.relay, &options.trust, &origin).await?;
    info!(broadcast = %name, relay = %options.relay, "publishing");
    let stats = Arc::new(Mutex::new(PublishStats {
        connects: 1,
        connected: true,
        ..PublishStats::default()
    }));
    let (close_tx, close_rx) = tokio::sync::oneshot::channel();
    let task = tokio::spawn(keep_linked(
        session,
        options.relay.clone(),
        options.trust.clone(),
        origin.clone(),
        stats.clone(),
        close_rx,
    ));
    let publishing = Publishing {
        broadcaster: Broadcaster::new(&info, options.policy),
        inner: source,
        tracks: Tracks {
            frames,
            digests,
            open: None,
        },
        stats: stats.clone(),
    };
    let link = Link {
        name,
        pool,
        stats,
        task,
        close: Some(close_tx),
        broadcast,
        _catalog: catalog,
        _origin: origin,
    };
    Ok((publishing, link))
}

/// Waits for the session to end, then re-establishes it, until aborted or
/// told to close (then it closes the session cleanly). The delay between
/// dials doubles from 0.25 s to 2 s, and starts over only after a session
/// that lasted 5 s (a relay that accepts and closes at once is not dialled
/// four times a second).
async fn keep_linked(
    mut session: moq_net::Session,
    relay: RelayUrl,
    trust: Trust,
    origin: origin::Producer,
    stats: Arc<Mutex<PublishStats>>,
    mut close: tokio::sync::oneshot::Receiver<()>,
) {
    let mut backoff = Duration::from_millis(250);
    loop {
        let began = Instant::now();
        let why = tokio::select! {
            why = session.closed() => why,
            _ = &mut close => {
                let _ = session.close().await;
                return;
            }
        };
        {
            let mut s = lock(&stats);
            s.connected = false;
            s.last_error = Some(format!("the session with the relay ended: {why}"));
        }
        warn!(relay = %relay, "the session with the relay ended: {why}");
        if began.elapsed() >= Duration::from_secs(5) {
            backoff = Duration::from_millis(250);
        }
        session = loop {
            tokio::select! {
                _ = tokio::time::sleep(backoff) => {}
                _ = &mut close => return,
            }
            backoff = (backoff * 2).min(Duration::from_secs(2));
            match connect(&relay, &trust, &origin).await {
                Ok(s) => break s,
                Err(e) => {
                    warn!(relay = %relay, "reconnecting: {e}");
                    lock(&stats).last_error = Some(format!("reconnecting: {e}"));
                }
            }
        };
        let mut s = lock(&stats);
        s.connects += 1;
        s.connected = true;
        info!(relay = %relay, "publishing again");
    }
}

/// The track producers a publication writes, and the open group.
struct Tracks {
    frames: track::Producer,
    digests: Option<track::Producer>,
    open: Option<group::Producer>,
}

impl Drop for Tracks {
    /// The broadcast's frames and digests end here: the open group and
    /// both tracks are finished (subscribers see them end, not fail).
    fn drop(&mut self) {
        if let Some(g) = self.open.take() {
            let _ = g.finish();
        }
        let _ = self.frames.finish();
        if let Some(d) = &self.digests {
            let _ = d.finish();
        }
    }
}

impl Tracks {
    fn write(&mut self, w: Write) -> Result<(), moq_net::Error> {
        match w {
            Write::Open { group, keyframe } => {
                if let Some(old) = self.open.take() {
                    old.finish()?;
                }
                let g = self.frames.create_group(group::Info { sequence: group })?;
                // Held before it is written to, so a failed write finishes
                // it (the caller) rather than dropping it mid-stream.
                self.open
                    .insert(g)
                    .write_frame(Timestamp::now(), keyframe)?;
            }
            Write::Append { frame, .. } => {
                if let Some(g) = self.open.as_mut() {
                    g.write_frame(Timestamp::now(), frame)?;
                }
            }
            Write::Digest { group, body } => {
                if let Some(d) = &self.digests {
                    let mut g = d.create_group(group::Info { sequence: group })?;
                    let written = g.write_frame(Timestamp::now(), body);
                    g.finish()?;
                    written?;
                }
            }
        }
        Ok(())
    }
}

/// A publisher stepping its source on a thread of its own.
pub struct Publisher<S> {
    stop: Arc<AtomicBool>,
    stepper: Option<std::thread::JoinHandle<Publishing<S>>>,
    /// Taken by [`Publisher::stop`].
    link: Option<Link>,
}

impl<S> std::fmt::Debug for Publisher<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("link", &self.link)
            .finish()
    }
}

/// Publishes `source`'s broadcast to a relay, stepping it on a thread of
/// its own at `frame_rate` until [`Publisher::stop`]. Returns once the
/// first session with the relay is up (an error otherwise); the session
/// is re-established (every 0.25 to 2 s) whenever the relay goes away.
pub async fn publish<S: FrameSource>(
    source: S,
    options: PublishOptions,
) -> Result<Publisher<S>, MoqError> {
    let (mut publishing, link) = publish_alongside(source, &options).await?;
    let stop = Arc::new(AtomicBool::new(false));
    let rate = options.frame_rate;
    let flag = stop.clone();
    let stepper = std::thread::Builder::new()
        .name("psao-moq-publish".into())
        .spawn(move || {
            let dt = 1.0 / rate as f32;
            let period = Duration::from_secs_f64(1.0 / rate as f64);
            let mut next = Instant::now() + period;
            let mut failures = 0u64;
            while !flag.load(Ordering::SeqCst) {
                if let Err(e) = publishing.step(dt) {
                    failures += 1;
                    lock(&publishing.stats).step_errors = failures;
                    // The first, then every 2^k-th: a source failing every
                    // step does not flood the log.
                    if failures.is_power_of_two() {
                        warn!("step failed ({failures} so far): {e}");
                    }
                }
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                    next += period;
                } else {
                    // Running late: no burst to catch up.
                    next = now + period;
                }
            }
            publishing
        })
        .map_err(|e| MoqError::Source(e.into()))?;
    Ok(Publisher {
        stop,
        stepper: Some(stepper),
        link: Some(link),
    })
}

impl<S: FrameSource> Publisher<S> {
    /// The broadcast's name.
    pub fn broadcast(&self) -> &str {
        self.link.as_ref().map_or("", |l| l.broadcast())
    }

    /// What it has done so far.
    pub fn stats(&self) -> PublishStats {
        self.link.as_ref().map(|l| l.stats()).unwrap_or_default()
    }

    /// Stops stepping, ends the tracks, the broadcast and the session
    /// cleanly ([`Link::close`]), and returns the source with the final
    /// figures.
    pub async fn stop(mut self) -> (S, PublishStats) {
        self.stop.store(true, Ordering::SeqCst);
        let stepper = self.stepper.take().expect("joined only here");
        let publishing = tokio::task::spawn_blocking(move || stepper.join())
            .await
            .expect("the join task is not cancelled")
            .unwrap_or_else(|p| std::panic::resume_unwind(p));
        let source = publishing.into_inner();
        let link = self.link.take().expect("taken only here");
        let stats = link.stats();
        link.close().await;
        (source, stats)
    }
}

impl<S> Drop for Publisher<S> {
    /// A publisher dropped without [`Publisher::stop`] stops stepping (its
    /// thread ends after the tick in progress); its link ends the
    /// broadcast.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}
