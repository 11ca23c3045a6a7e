//! The subscriber: follows one broadcast through a relay into a
//! [`Follower`] (spec/moq.md 3-5). It reads the catalog, then the
//! `frames` track group by group (a newer group replaces the one being
//! read) and the `digest` track; when the session or the broadcast ends
//! it subscribes again, through the next relay of its list when the one it
//! used failed, keeping its mirror (for a viewer to draw) until the new
//! subscription starts from no state.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use moq_net::{broadcast, group, origin};
use psao_codec::Limits;
use psao_proto::tls::Trust;
use tracing::{debug, warn};

use super::dial::{MoqError, RelayUrl, dial};
use crate::catalog::track as names;
use crate::follower::{FollowStats, Follower};

/// What to follow, through which relays.
#[derive(Clone, Debug)]
pub struct SubscribeOptions {
    /// Relays to subscribe through, tried in order (the next when one
    /// fails); each URL's path is the broadcast.
    pub relays: Vec<RelayUrl>,
    /// How the relays' certificates are checked.
    pub trust: Trust,
    /// The subscriber's decoding limits.
    pub limits: Limits,
    /// Whether to follow the `digest` track (when the catalog has one).
    pub digests: bool,
    /// Keep every `frames` frame received, with when it arrived, for
    /// [`Subscription::take_captured`] (at most [`MAX_CAPTURED`] waiting).
    pub capture: bool,
}

/// Most captured frames waiting for [`Subscription::take_captured`]; older
/// ones are dropped (and counted).
pub const MAX_CAPTURED: usize = 4096;

/// Most bytes of captured frames waiting (older ones are dropped).
pub const MAX_CAPTURED_BYTES: usize = 64 << 20;

/// How long a subscriber waits for its broadcast to be announced through a
/// relay before it tries the next relay of its list.
pub const ANNOUNCE_TIMEOUT: Duration = Duration::from_secs(10);

/// What a subscription has seen.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SubscribeStats {
    /// The follower's counts (since the last restart of the mirror).
    pub follow: FollowStats,
    /// Sessions established with relays.
    pub connects: u64,
    /// Index in the relay list of the relay in use (or last tried).
    pub relay: usize,
    /// Mirrors discarded as a new subscription started (spec/moq.md 4,
    /// restarts).
    pub restarts: u64,
    /// From [`subscribe`] to the first keyframe applied.
    pub join_time: Option<Duration>,
    /// The last error that ended a session.
    pub last_error: Option<String>,
    /// Groups whose stream ended in an error (reset by a relay, expired,
    /// served from a later frame): each is a lost group, survived
    /// (spec/moq.md 4).
    pub groups_failed: u64,
}

#[derive(Debug)]
struct Shared {
    follower: Follower,
    stats: SubscribeStats,
    fatal: Option<String>,
    captured: std::collections::VecDeque<(Instant, bytes::Bytes)>,
    captured_bytes: usize,
    dropped: u64,
}

/// A running subscription.
#[derive(Debug)]
pub struct Subscription {
    shared: Arc<Mutex<Shared>>,
    task: tokio::task::JoinHandle<()>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Starts following a broadcast; returns at once (the session is set up in
/// the background: see [`Subscription::stats`] and
/// [`Subscription::failed`]).
pub fn subscribe(options: SubscribeOptions) -> Result<Subscription, MoqError> {
    if options.relays.is_empty() {
        return Err(MoqError::Url {
            url: String::new(),
            why: "no relay given",
        });
    }
    if let Some(r) = options.relays.iter().find(|r| r.path.is_empty()) {
        return Err(MoqError::Url {
            url: r.to_string(),
            why: "its path (the broadcast) is empty",
        });
    }
    let shared = Arc::new(Mutex::new(Shared {
        follower: Follower::new(options.limits),
        stats: SubscribeStats::default(),
        fatal: None,
        captured: Default::default(),
        captured_bytes: 0,
        dropped: 0,
    }));
    let task = tokio::spawn(run(options, shared.clone(), Instant::now()));
    Ok(Subscription { shared, task })
}

impl Subscription {
    /// Runs `f` on the follower (its mirror, decoder and catalog). The
    /// subscription waits meanwhile: keep `f` short, and call no other
    /// method of this subscription inside it (they take the same lock).
    pub fn with_follower<R>(&self, f: impl FnOnce(&mut Follower) -> R) -> R {
        f(&mut lock(&self.shared).follower)
    }

    /// What it has seen so far.
    pub fn stats(&self) -> SubscribeStats {
        let s = lock(&self.shared);
        SubscribeStats {
            follow: s.follower.stats(),
            ..s.stats.clone()
        }
    }

    /// Why it stopped for good (a broadcast it cannot follow), if it did.
    pub fn failed(&self) -> Option<String> {
        lock(&self.shared).fatal.clone()
    }

    /// The frames captured since the last call (with `capture` set), in
    /// the order they arrived, and how many were dropped because more than
    /// [`MAX_CAPTURED`] waited.
    pub fn take_captured(&self) -> (Vec<(Instant, bytes::Bytes)>, u64) {
        let mut s = lock(&self.shared);
        let dropped = std::mem::take(&mut s.dropped);
        s.captured_bytes = 0;
        (s.captured.drain(..).collect(), dropped)
    }

    /// Whether its mirror follows the broadcast now.
    pub fn in_sync(&self) -> bool {
        lock(&self.shared).follower.in_sync()
    }

    /// Ends the subscription.
    pub fn close(self) {
        self.task.abort();
    }
}

impl Drop for Subscription {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Subscribes, again and again, until a fatal error. A relay that failed
/// (or never announced the broadcast) is left for the next of the list;
/// the delay between attempts doubles from 0.1 s to 2 s and starts over
/// after a session that lasted 5 s.
async fn run(options: SubscribeOptions, shared: Arc<Mutex<Shared>>, started: Instant) {
    let n = options.relays.len();
    let mut index = 0;
    let mut backoff = Duration::from_millis(100);
    loop {
        let url = &options.relays[index];
        lock(&shared).stats.relay = index;
        let began = Instant::now();
        let result = follow_once(url, &options, &shared, started).await;
        {
            let mut s = lock(&shared);
            match &result {
                Err(MoqError::Follow(e)) => {
                    warn!(relay = %url, "cannot follow the broadcast: {e}");
                    s.fatal = Some(e.to_string());
                    return;
                }
                Err(e) => {
                    warn!(relay = %url, "subscription ended: {e}");
                    s.stats.last_error = Some(e.to_string());
                }
                Ok(()) => s.stats.last_error = Some("the broadcast ended".into()),
            }
        }
        if began.elapsed() >= Duration::from_secs(5) {
            backoff = Duration::from_millis(100);
        }
        // A relay that failed: try the next one. A broadcast that ended
        // cleanly: the same relay again (it may be announced anew).
        if result.is_err() {
            index = (index + 1) % n;
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(Duration::from_secs(2));
    }
}

/// One session: connect, wait for the broadcast, read its catalog, then
/// follow its tracks until something ends. `Ok` when the broadcast ended
/// cleanly.
async fn follow_once(
    url: &RelayUrl,
    options: &SubscribeOptions,
    shared: &Arc<Mutex<Shared>>,
    started: Instant,
) -> Result<(), MoqError> {
    let transport = dial(url, &options.trust).await?;
    let (origin, driver) = origin::Producer::new(origin::Config::default());
    let origin_task = tokio::spawn(moq_net::time::run(driver));
    let _origin_task = AbortOnDrop(origin_task);
    let client = moq_net::Client::new().with_subscriber(origin.clone());
    let (session, driver) = tokio::time::timeout(
        super::dial::SETUP_TIMEOUT,
        client.connect(Instant::now(), transport),
    )
    .await
    .map_err(|_| MoqError::Timeout("the MoQ setup with the relay"))??;
    let _session_task = AbortOnDrop(tokio::spawn(moq_net::time::run(driver)));
    lock(shared).stats.connects += 1;
    tokio::select! {
        r = follow_broadcast(&origin, url, options, shared, started) => r,
        e = session.closed() => Err(MoqError::Moq(e)),
    }
}

struct AbortOnDrop<T>(tokio::task::JoinHandle<T>);

impl<T> Drop for AbortOnDrop<T> {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Waits (at most [`ANNOUNCE_TIMEOUT`]) for the broadcast at `path` to be
/// routed through the relay.
async fn announced(origin: &origin::Producer, path: &str) -> Result<broadcast::Consumer, MoqError> {
    tokio::time::timeout(ANNOUNCE_TIMEOUT, origin.consume().routed_broadcast(path))
        .await
        .map_err(|_| MoqError::Timeout("the broadcast to be announced through the relay"))?
        .map_err(MoqError::Moq)
}

async fn follow_broadcast(
    origin: &origin::Producer,
    url: &RelayUrl,
    options: &SubscribeOptions,
    shared: &Arc<Mutex<Shared>>,
    started: Instant,
) -> Result<(), MoqError> {
    let broadcast = announced(origin, &url.path).await?;
    {
        // A new subscription starts from no state (spec/moq.md 4,
        // restarts); until now the mirror of the last one was kept, for a
        // viewer to go on drawing.
        let mut s = lock(shared);
        if s.follower.mirror().sequence().is_some() {
            s.stats.restarts += 1;
        }
        s.follower.restart();
    }
    // The catalog first (spec/moq.md 3), read anew for each subscription.
    let mut catalog = broadcast.track(names::CATALOG)?.subscribe(None).await?;
    let g = catalog.recv_group().await?.ok_or(MoqError::Timeout(
        "the catalog track ended before its group",
    ))?;
    let mut one = Some(Reading::from(g));
    // A WELCOME body is at most 16 + 200 bytes: a larger catalog frame is
    // not read (malformed).
    let (_, _, frame) = next_frame(&mut one, psao_proto::control::MAX_CONTROL_LEN as u64)
        .await?
        .ok_or(MoqError::Timeout(
            "the catalog group ended before its frame",
        ))?;
    let (digest_track, max_frame) = {
        let mut s = lock(shared);
        let w = s.follower.on_catalog(&frame)?;
        (w.digest && options.digests, u64::from(w.max_frame_bytes))
    };
    let mut frames = broadcast.track(names::FRAMES)?.subscribe(None).await?;
    // A digest track the catalog announces but the relay cannot serve:
    // follow the frames without digests.
    let mut digests = match digest_track {
        true => match broadcast.track(names::DIGEST) {
            Ok(t) => match t.subscribe(None).await {
                Ok(t) => Some(t),
                Err(e) => {
                    warn!("the digest track: {e}; following without digests");
                    None
                }
            },
            Err(e) => {
                warn!("the digest track: {e}; following without digests");
                None
            }
        },
        false => None,
    };
    let mut current: Option<Reading> = None;
    let mut digest_group: Option<Reading> = None;
    // Once the frames track ended, the group being read is read to its end
    // (its last frames can arrive after the track's end), then the
    // broadcast has ended.
    let mut track_open = true;
    loop {
        if !track_open && current.is_none() {
            return Ok(());
        }
        tokio::select! {
            g = frames.recv_group(), if track_open => match g? {
                None => track_open = false,
                Some(g) => {
                    if current.as_ref().is_none_or(|c| g.sequence > c.group.sequence) {
                        current = Some(g.into());
                    }
                }
            },
            f = next_frame(&mut current, max_frame) => match f {
                Ok(Some((id, index, payload))) => {
                    let mut s = lock(shared);
                    if options.capture {
                        s.captured_bytes += payload.len();
                        s.captured.push_back((Instant::now(), payload.clone()));
                        while s.captured.len() > MAX_CAPTURED || s.captured_bytes > MAX_CAPTURED_BYTES {
                            let Some((_, old)) = s.captured.pop_front() else { break };
                            s.captured_bytes -= old.len();
                            s.dropped += 1;
                        }
                    }
                    let applied = matches!(
                        s.follower.on_frame(id, index, &payload),
                        crate::Followed::Applied { keyframe: true, .. }
                    );
                    if applied && s.stats.join_time.is_none() {
                        s.stats.join_time = Some(started.elapsed());
                    }
                    if let Some(e) = s.follower.gave_up() {
                        return Err(MoqError::Follow(e));
                    }
                }
                Ok(None) => current = None,
                // One group failed (reset, expired, lagged): a lost group,
                // which the next group's keyframe repairs (spec/moq.md 4).
                Err(e) => {
                    debug!("a frames group ended early: {e}");
                    lock(shared).stats.groups_failed += 1;
                    current = None;
                }
            },
            g = next_digest_group(&mut digests) => match g? {
                Some(g) => digest_group = Some(g.into()),
                None => digests = None,
            },
            f = next_frame(&mut digest_group, DIGEST_FRAME_MAX) => match f {
                Ok(Some((_, _, payload))) => {
                    let mut s = lock(shared);
                    // A malformed digest is ignored (spec/moq.md 5).
                    if let Err(e) = s.follower.on_digest(&payload) {
                        warn!("a digest frame ignored: {e}");
                    }
                }
                Ok(None) | Err(_) => digest_group = None,
            },
        }
    }
}

/// The largest `digest` frame read (a `DIGEST` body is 8 bytes).
const DIGEST_FRAME_MAX: u64 = 64;

/// A group being read, and the frame being read in it. The frame is kept
/// here, not in the future that reads it, so that reading is
/// cancellation-safe: the `select!` in [`follow_broadcast`] drops the
/// future whenever another branch is ready first (a digest, an older
/// group, the track's end), and a frame whose bytes were still arriving
/// would otherwise be lost with it, mid-group (the group then breaks, and a
/// lost keyframe costs the whole group). A newer group replaces the
/// `Reading` whole, frame and all: the newest group wins (spec/moq.md 4).
struct Reading {
    group: group::Consumer,
    /// The frame's index in the group and its consumer, once it is known.
    frame: Option<(u64, moq_net::frame::Consumer)>,
}

impl From<group::Consumer> for Reading {
    fn from(group: group::Consumer) -> Reading {
        Reading { group, frame: None }
    }
}

/// The next frame of the group being read (id, index, payload); never
/// resolves without one. A frame whose declared size is above `max` (the
/// catalog's `max_frame_bytes`) is not read: an error, which ends that
/// group as a lost one (spec/moq.md 4), before its bytes are gathered.
/// Cancellation-safe: a call dropped at any await leaves the group and the
/// frame where they were, and the next call goes on from there.
async fn next_frame(
    reading: &mut Option<Reading>,
    max: u64,
) -> Result<Option<(u64, u64, bytes::Bytes)>, MoqError> {
    let Some(r) = reading.as_mut() else {
        return std::future::pending().await;
    };
    if r.frame.is_none() {
        let index = r.group.index();
        // Resolves only with the frame, and within the poll that takes it
        // from the group: nothing is taken by a call dropped here.
        let Some(f) = r.group.next_frame().await? else {
            return Ok(None);
        };
        if f.size > max {
            return Err(MoqError::FrameTooLarge { size: f.size, max });
        }
        r.frame = Some((index, f));
    }
    let (index, f) = r.frame.as_mut().expect("set above");
    // read_all keeps what arrived in the frame consumer until all of it has.
    let payload = f.read_all().await?;
    let index = *index;
    r.frame = None;
    Ok(Some((r.group.sequence, index, payload)))
}

async fn next_digest_group(
    track: &mut Option<moq_net::track::Subscriber>,
) -> Result<Option<group::Consumer>, MoqError> {
    let Some(t) = track.as_mut() else {
        return std::future::pending().await;
    };
    Ok(t.recv_group().await?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use moq_net::{Timestamp, frame};

    /// A read dropped while a frame's bytes are still arriving (what
    /// `select!` does when a digest or the track's end comes first) loses
    /// nothing: the next read returns that frame whole, then the next one.
    #[tokio::test]
    async fn a_frame_read_dropped_midway_is_read_whole_next_time() {
        let broadcast = broadcast::Info::new().produce();
        let track = broadcast.create_track(names::FRAMES, None).unwrap();
        let mut group = track.create_group(group::Info { sequence: 3 }).unwrap();
        let mut reading = Some(Reading::from(group.consume()));
        {
            let mut f = group
                .create_frame(frame::Info {
                    size: 6,
                    timestamp: Timestamp::now(),
                })
                .unwrap();
            f.write(bytes::Bytes::from_static(b"key")).unwrap();
            // Half the frame has arrived: the read cannot finish, and is
            // dropped as select! drops it.
            let cut = tokio::time::timeout(Duration::from_millis(50), next_frame(&mut reading, 64));
            assert!(cut.await.is_err(), "a read of half a frame returned");
            f.write(bytes::Bytes::from_static(b"fra")).unwrap();
            f.finish().unwrap();
        }
        group
            .write_frame(Timestamp::now(), bytes::Bytes::from_static(b"delta"))
            .unwrap();
        group.finish().unwrap();
        let (id, index, payload) = next_frame(&mut reading, 64).await.unwrap().unwrap();
        assert_eq!((id, index, &payload[..]), (3, 0, &b"keyfra"[..]));
        let (id, index, payload) = next_frame(&mut reading, 64).await.unwrap().unwrap();
        assert_eq!((id, index, &payload[..]), (3, 1, &b"delta"[..]));
        assert!(next_frame(&mut reading, 64).await.unwrap().is_none());
    }

    /// A frame declared above the limit is refused before its bytes are
    /// read, and says how large it is.
    #[tokio::test]
    async fn a_frame_above_the_limit_is_refused_by_its_size() {
        let broadcast = broadcast::Info::new().produce();
        let track = broadcast.create_track(names::FRAMES, None).unwrap();
        let mut group = track.create_group(group::Info { sequence: 0 }).unwrap();
        let mut reading = Some(Reading::from(group.consume()));
        group
            .write_frame(Timestamp::now(), bytes::Bytes::from(vec![0u8; 65]))
            .unwrap();
        match next_frame(&mut reading, 64).await {
            Err(MoqError::FrameTooLarge { size: 65, max: 64 }) => {}
            other => panic!("{other:?}"),
        }
    }
}
