//! The reference server: one frame source, many clients, over QUIC (quinn
//! and tokio). The session logic is sans-IO: [`ServerConn`] per
//! connection and the [`Fanout`] policy over all of them; this module is
//! the I/O around them.
//!
//! A stepping thread steps the [`FrameSource`] at the frame rate. Each
//! frame is encoded once; its bytes (shared, not copied) go into every
//! in-sync client's outbox. A writer task per client drains its outbox
//! onto the client's frame stream. A client that cannot keep up falls
//! behind (its queued frames are dropped) and gets a keyframe once it has
//! drained, so a stalled client costs at most `max_queue_bytes` of deltas,
//! one keyframe, the frame being written, 16 notices and the QUIC send
//! window.

use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use glam::Affine3A;
use tokio::sync::Notify;
use tracing::{debug, info, trace, warn};

use crate::codes::{Close, CloseCode, SessionError};
use crate::control::NoticeCode;
use crate::fanout::{ClientId, Fanout, Keyframes, Transmit};
use crate::link::{Binding, Link, LinkRecv, LinkSend, Read};
use crate::own_mirror::OwnMirror;
use crate::records::record_prefix;
use crate::server_conn::{Offer, ServerConn, ServerEvent};
use crate::source::{ClientViews, FrameSource, StepReport};
use crate::tls::{Identity, TlsError, server_config};

/// Server settings.
#[derive(Clone, Debug)]
pub struct ServerConfig {
    /// Address to listen on.
    pub bind: SocketAddr,
    /// Frames per second.
    pub frame_rate: u16,
    /// Most clients at once; more are closed with `server_full`.
    pub max_clients: usize,
    /// Most bytes of frames queued for one client (spec/session.md, 5.2).
    pub max_queue_bytes: usize,
    /// Whether clients may move instances (`MOVE_INSTANCE`).
    pub allow_events: bool,
    /// The scene's name, sent in `WELCOME`.
    pub scene_name: String,
    /// A client silent this long (QUIC idle timeout) is dropped.
    pub idle_timeout: Duration,
    /// Mirror digests (spec/session.md 3.8) for clients that check them:
    /// one every this many frames written to a client, until it asks for
    /// another interval. 0: digests are not offered (the server then
    /// keeps no mirror of its own stream). Default 60.
    pub digest_interval: u16,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            frame_rate: 60,
            max_clients: 256,
            max_queue_bytes: 1 << 20,
            allow_events: true,
            scene_name: "default".into(),
            idle_timeout: Duration::from_secs(10),
            digest_interval: DIGEST_INTERVAL,
        }
    }
}

/// The reference server's default digest interval, in frames.
pub const DIGEST_INTERVAL: u16 = 60;

/// The shortest digest interval a client may ask for (`DIGEST_REQUEST`
/// with a smaller non-zero `every` gets this).
pub const MIN_DIGEST_EVERY: u16 = 10;

/// Errors starting a server.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ServeError {
    /// TLS setup failed.
    #[error(transparent)]
    Tls(#[from] TlsError),
    /// The socket could not be bound.
    #[error("cannot listen on {addr}: {reason}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
    /// A setting is out of range.
    #[error("setting `{0}` is out of range")]
    Setting(&'static str),
    /// The server failed while stopping.
    #[error("server stopped abnormally: {0}")]
    Stopped(String),
}

/// Counters of a running server.
#[derive(Clone, Debug, Default)]
pub struct ServerStats {
    /// Frames stepped.
    pub frames: u64,
    /// Frames that had something to send.
    pub sent_frames: u64,
    /// Bytes of frames encoded (once, whatever the number of clients).
    pub encoded_bytes: u64,
    /// Bytes written to all clients (records included).
    pub written_bytes: u64,
    /// Keyframes encoded.
    pub keyframes: u64,
    /// Times a client fell behind.
    pub falls: u64,
    /// Keyframes written to resynchronize a client that fell behind, each
    /// after a `NOTICE` code 2 (at most `falls`: a fall while a resync
    /// keyframe still waits drops it, and the next one resynchronizes).
    pub resyncs: u64,
    /// The largest frame sent so far (bytes, without the record prefix),
    /// keyframes included: a client must accept at least this to join.
    pub largest_frame: u32,
    /// Clients connected now.
    pub clients: usize,
    /// Clients that completed a handshake since the start.
    pub accepted: u64,
    /// The last frame's sequence.
    pub sequence: u32,
    /// Sum of the per-frame reports.
    pub report: StepReport,
    /// Time spent stepping the source.
    pub step_time: Duration,
    /// The longest step of the source so far (the source's `step` alone:
    /// keyframes and digests not included).
    pub longest_step: Duration,
    /// Ticks that started at once, behind their schedule (the tick before
    /// them ended after they were due: [`rate::TickSchedule`](crate::rate::TickSchedule)).
    /// Those within [`rate::catch_up_limit`](crate::rate::catch_up_limit)
    /// kept the schedule, and were made up; a server always behind counts
    /// every tick here.
    pub behind_ticks: u64,
    /// Ticks given up because the server fell more than
    /// [`rate::catch_up_limit`](crate::rate::catch_up_limit) behind its
    /// schedule.
    pub lost_ticks: u64,
    /// The furthest behind its schedule the server has been when a tick
    /// ended, since it started (see `behind_ticks`).
    pub most_behind: Duration,
    /// Mean of the clients' last frame age (from a frame's send to its
    /// `ACK`), seconds.
    pub frame_age: f64,
    /// The largest bytes queued for one client right now.
    pub max_queued: usize,
    /// Times the server told its clients it runs below its announced
    /// frame rate (`NOTICE` code 4).
    pub rate_notices: u64,
}

/// The I/O side of a client: its writer's wake-up, its frame age and
/// what its connection has sent.
struct Slot {
    wake: Arc<Notify>,
    /// Seconds from a frame's broadcast to the client's `ACK` of it.
    frame_age: f64,
    /// Its binding (spec/session.md 2 or 9).
    binding: Binding,
    /// Frame records and their bytes written to it.
    frames: u64,
    record_bytes: u64,
    /// UDP bytes its connection sent so far (QUIC's own count).
    udp_sent: Arc<dyn Fn() -> u64 + Send + Sync>,
}

/// One client's figures now.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClientFigures {
    /// Its binding.
    pub binding: Binding,
    /// Frame records written to it.
    pub frames: u64,
    /// Their bytes (prefixes included).
    pub record_bytes: u64,
    /// UDP bytes its connection sent (QUIC and, for WebTransport, HTTP/3
    /// framing included; handshake, acknowledgements and pings too).
    pub udp_sent: u64,
    /// Seconds from the broadcast of the last frame it acknowledged to its
    /// `ACK`.
    pub frame_age: f64,
}

struct HubState {
    /// The session policy: outboxes, shared keyframes, notices, views.
    fanout: Fanout,
    clients: HashMap<ClientId, Slot>,
    moves: Vec<(ClientId, u32, Affine3A)>,
    stats: ServerStats,
    /// When recent sequences were broadcast.
    sent_at: VecDeque<(u32, Instant)>,
}

impl HubState {
    /// Wakes every client's writer.
    fn wake_all(&self) {
        for c in self.clients.values() {
            c.wake.notify_one();
        }
    }

    /// Queues a notice for every client and wakes their writers.
    fn notice_all(&mut self, code: NoticeCode, text: &str) {
        let ids: Vec<ClientId> = self.clients.keys().copied().collect();
        for id in ids {
            self.notice(id, code, text);
        }
    }

    /// Queues a notice for `client` and wakes its writer.
    fn notice(&mut self, client: ClientId, code: NoticeCode, text: &str) {
        if self.fanout.notice(client, code, text)
            && let Some(c) = self.clients.get(&client)
        {
            c.wake.notify_one();
        }
    }
}

pub(crate) struct Hub {
    state: Mutex<HubState>,
    /// The stepping thread stops.
    stop: AtomicBool,
    /// Writers finish their frame streams once drained (set after the
    /// source's last frame was queued).
    closing: AtomicBool,
    /// Writer tasks still running.
    writers: std::sync::atomic::AtomicUsize,
    /// What `WELCOME` offers.
    offer: Offer,
    config: ServerConfig,
    /// How to close each open WebTransport session with a capsule, for
    /// shutdown (spec/session.md 9.3), by a number of its own.
    web_sessions: Mutex<HashMap<u64, SessionCloser>>,
    next_web_session: std::sync::atomic::AtomicU64,
}

/// Closes one session with a code and reason.
type SessionCloser = Box<dyn Fn(u32, &[u8]) + Send>;

impl Hub {
    fn lock(&self) -> MutexGuard<'_, HubState> {
        // A panic while holding the lock leaves counters only; go on.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A running server of a source `S`.
pub struct ServerHandle<S> {
    hub: Arc<Hub>,
    endpoint: quinn::Endpoint,
    addr: SocketAddr,
    fingerprint: [u8; 32],
    stepper: Option<std::thread::JoinHandle<S>>,
    acceptor: tokio::task::JoinHandle<()>,
    /// The WebTransport endpoint and its acceptor, once listening
    /// (feature `web`).
    web: Option<(quinn::Endpoint, tokio::task::JoinHandle<()>)>,
}

impl<S> std::fmt::Debug for ServerHandle<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServerHandle")
            .field("addr", &self.addr)
            .finish()
    }
}

impl<S: FrameSource> ServerHandle<S> {
    /// Where it listens.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// SHA-256 of its certificate, for clients to pin.
    pub fn fingerprint(&self) -> [u8; 32] {
        self.fingerprint
    }

    /// A counter of the frames stepped so far, for another task (the
    /// scene time is that over the frame rate).
    pub fn frames_stepped(&self) -> impl Fn() -> u64 + Send + Sync + 'static {
        let hub = self.hub.clone();
        move || hub.lock().stats.frames
    }

    /// Every connected client's figures, by binding.
    pub fn client_figures(&self) -> Vec<ClientFigures> {
        // The connections' own counters are read outside the hub's lock.
        let taken: Vec<_> = {
            let s = self.hub.lock();
            s.clients
                .values()
                .map(|c| {
                    (
                        c.binding,
                        c.frames,
                        c.record_bytes,
                        c.frame_age,
                        c.udp_sent.clone(),
                    )
                })
                .collect()
        };
        taken
            .into_iter()
            .map(
                |(binding, frames, record_bytes, frame_age, udp)| ClientFigures {
                    binding,
                    frames,
                    record_bytes,
                    udp_sent: udp(),
                    frame_age,
                },
            )
            .collect()
    }

    /// Where its WebTransport endpoint listens, if it does (feature
    /// `web`: `listen_web`).
    pub fn web_addr(&self) -> Option<SocketAddr> {
        self.web_endpoint().and_then(|e| e.local_addr().ok())
    }

    pub(crate) fn web_endpoint(&self) -> Option<&quinn::Endpoint> {
        self.web.as_ref().map(|w| &w.0)
    }

    #[cfg_attr(not(feature = "web"), allow(dead_code))]
    pub(crate) fn set_web(
        &mut self,
        endpoint: quinn::Endpoint,
        acceptor: tokio::task::JoinHandle<()>,
    ) {
        self.web = Some((endpoint, acceptor));
    }

    #[cfg_attr(not(feature = "web"), allow(dead_code))]
    pub(crate) fn hub(&self) -> Arc<Hub> {
        self.hub.clone()
    }

    #[cfg_attr(not(feature = "web"), allow(dead_code))]
    pub(crate) fn config(&self) -> &ServerConfig {
        &self.hub.config
    }

    /// Counters now.
    pub fn stats(&self) -> ServerStats {
        let s = self.hub.lock();
        let mut st = s.stats.clone();
        st.clients = s.clients.len();
        let ages: Vec<f64> = s.clients.values().map(|c| c.frame_age).collect();
        st.frame_age = ages.iter().sum::<f64>() / ages.len().max(1) as f64;
        st.max_queued = s.fanout.max_queued_bytes();
        st.falls = s.fanout.falls();
        st.resyncs = s.fanout.resyncs();
        st.largest_frame = s.fanout.largest().0;
        st
    }

    /// Stops stepping, lets writers flush what is queued (at most
    /// `grace`), closes every connection with `server_shutdown` and
    /// returns the source (its state is what in-sync clients mirror) and
    /// the final counters.
    pub async fn shutdown(mut self, grace: Duration) -> Result<(S, ServerStats), ServeError> {
        self.acceptor.abort();
        if let Some((_, acceptor)) = &self.web {
            acceptor.abort();
        }
        self.hub.stop.store(true, Ordering::SeqCst);
        let stepper = self.stepper.take();
        let source = tokio::task::spawn_blocking(move || stepper.map(|h| h.join()))
            .await
            .ok()
            .flatten()
            .and_then(|r| r.ok());
        // The last frame is queued: writers drain their outboxes, finish
        // their frame streams and wait (up to 1 s) for the client to
        // acknowledge them.
        self.hub.closing.store(true, Ordering::SeqCst);
        self.hub.lock().wake_all();
        let until = Instant::now() + grace;
        while Instant::now() < until && self.hub.writers.load(Ordering::SeqCst) > 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let stats = self.stats();
        // WebTransport sessions get their capsule first, and a moment for
        // it to go out (spec/session.md 9.3).
        let web: Vec<SessionCloser> = lock_sessions(&self.hub).drain().map(|(_, c)| c).collect();
        for close in &web {
            close(CloseCode::ServerShutdown.code(), b"server shutdown");
        }
        if !web.is_empty() {
            tokio::time::sleep(WEB_CLOSE_WAIT).await;
        }
        self.close_endpoints();
        self.endpoint.wait_idle().await;
        if let Some((web, _)) = &self.web {
            web.wait_idle().await;
        }
        let source = source.ok_or(ServeError::Stopped("the stepping thread panicked".into()))?;
        Ok((source, stats))
    }
}

impl<S> Drop for ServerHandle<S> {
    /// A handle dropped without [`shutdown`](ServerHandle::shutdown) still
    /// stops the server: stepping ends, the listener goes and every
    /// connection is closed with `server_shutdown`.
    fn drop(&mut self) {
        self.hub.stop.store(true, Ordering::SeqCst);
        self.hub.closing.store(true, Ordering::SeqCst);
        self.acceptor.abort();
        if let Some((_, acceptor)) = &self.web {
            acceptor.abort();
        }
        self.close_endpoints();
    }
}

impl<S> ServerHandle<S> {
    /// Closes every connection of both endpoints: the native ones with
    /// `server_shutdown`, the WebTransport ones with HTTP/3's
    /// `H3_NO_ERROR` after their frame streams finished (spec/session.md
    /// 9.3).
    fn close_endpoints(&self) {
        let code = CloseCode::ServerShutdown.code();
        self.endpoint
            .close(quinn::VarInt::from_u32(code), b"server shutdown");
        if let Some((web, _)) = &self.web {
            web.close(quinn::VarInt::from_u32(H3_NO_ERROR), b"server shutdown");
        }
    }
}

/// How long the server waits for the client's transport parameters to
/// let it open the frame stream after `WELCOME` (spec/session.md 2).
pub const FRAME_STREAM_WAIT: Duration = Duration::from_secs(1);

/// Starts a server streaming `source`'s frames.
pub async fn serve<S: FrameSource>(
    source: S,
    config: ServerConfig,
    identity: &Identity,
) -> Result<ServerHandle<S>, ServeError> {
    if config.frame_rate == 0 || config.frame_rate > 1000 {
        return Err(ServeError::Setting("frame_rate (1..=1000)"));
    }
    if config.max_queue_bytes < 1024 {
        return Err(ServeError::Setting("max_queue_bytes (at least 1024)"));
    }
    let info = source.info();
    let offer = Offer {
        compression: info.compression,
        max_frame_bytes: info.max_frame_bytes,
        max_payload_bytes: info.max_payload_bytes,
        largest_frame: 0,
        largest_payload: 0,
        mirror_bytes: info.mirror_bytes,
        point_format: info.point_format,
        overflow: info.overflow,
        frame_rate: config.frame_rate,
        scene: config.scene_name.clone(),
        culling: info.culls,
        digest: config.digest_interval > 0,
    };
    let endpoint =
        quinn::Endpoint::server(server_config(identity, config.idle_timeout)?, config.bind)
            .map_err(|e| ServeError::Bind {
                addr: config.bind,
                reason: e.to_string(),
            })?;
    let addr = endpoint.local_addr().map_err(|e| ServeError::Bind {
        addr: config.bind,
        reason: e.to_string(),
    })?;
    let hub = Arc::new(Hub {
        state: Mutex::new(HubState {
            fanout: Fanout::new(config.max_queue_bytes),
            clients: HashMap::new(),
            moves: Vec::new(),
            stats: ServerStats::default(),
            sent_at: VecDeque::new(),
        }),
        stop: AtomicBool::new(false),
        closing: AtomicBool::new(false),
        web_sessions: Mutex::new(HashMap::new()),
        next_web_session: std::sync::atomic::AtomicU64::new(0),
        writers: std::sync::atomic::AtomicUsize::new(0),
        offer,
        config,
    });
    let stepper = {
        let hub = hub.clone();
        std::thread::Builder::new()
            .name("psao-step".into())
            .spawn(move || step_loop(source, &hub))
            .map_err(|e| ServeError::Bind {
                addr,
                reason: format!("cannot start the stepping thread: {e}"),
            })?
    };
    let acceptor = {
        let (hub, endpoint) = (hub.clone(), endpoint.clone());
        tokio::spawn(async move {
            while let Some(incoming) = endpoint.accept().await {
                let hub = hub.clone();
                tokio::spawn(async move {
                    match incoming.await {
                        Ok(conn) => serve_connection(hub, conn).await,
                        Err(e) => debug!("handshake failed: {e}"),
                    }
                });
            }
        })
    };
    info!(%addr, "serving");
    Ok(ServerHandle {
        hub,
        endpoint,
        addr,
        fingerprint: identity.fingerprint(),
        stepper: Some(stepper),
        acceptor,
        web: None,
    })
}

/// The stepping thread: step, broadcast, keyframes; returns the source
/// when told to stop.
fn step_loop<S: FrameSource>(mut source: S, hub: &Hub) -> S {
    let dt = 1.0 / hub.config.frame_rate as f32;
    let mut schedule = crate::rate::TickSchedule::new(hub.config.frame_rate, Instant::now());
    let mut watch = crate::rate::RateWatch::new(hub.config.frame_rate);
    // A mirror of the server's own stream, for digests: every frame and
    // keyframe handed to the fan-out is applied to it.
    let mut own = (hub.config.digest_interval > 0).then(|| OwnMirror::new(&source.info()));
    while !hub.stop.load(Ordering::SeqCst) {
        // Scene events first, so the frame carries them.
        let moves = std::mem::take(&mut hub.lock().moves);
        for (client, instance, t) in moves {
            if let Err(e) = source.place(instance, t) {
                hub.lock()
                    .notice(client, NoticeCode::EventRefused, &e.to_string());
            }
        }
        if hub.offer.culling {
            let poses = hub.lock().fanout.views();
            source.set_views(match &poses {
                Some(p) => ClientViews::Poses(p),
                None => ClientViews::All,
            });
        }
        let t0 = Instant::now();
        let stepped = source.step(dt);
        let step_time = t0.elapsed();
        let (frame, report) = match stepped {
            Ok(x) => x,
            Err(e) => {
                warn!("step failed: {e}");
                (None, StepReport::default())
            }
        };
        // The server's own mirror and its digest, outside the hub's lock
        // (a digest reads the whole mirror).
        let idle_at = match &frame {
            Some(_) => None,
            None => own.as_ref().and_then(|m| m.sequence()),
        };
        let wanted = hub.lock().fanout.wants_digest(false, idle_at);
        let digest = digest_after(&mut own, frame.as_ref(), wanted);
        let wants_keyframe = {
            let mut s = hub.lock();
            s.stats.frames += 1;
            s.stats.step_time += step_time;
            s.stats.longest_step = s.stats.longest_step.max(step_time);
            s.stats.report.accumulate(&report);
            if let Some(f) = &frame {
                s.stats.sent_frames += 1;
                s.stats.encoded_bytes += f.bytes.len() as u64;
                s.stats.sequence = f.sequence;
                s.sent_at.push_back((f.sequence, Instant::now()));
                if s.sent_at.len() > 512 {
                    s.sent_at.pop_front();
                }
                s.fanout.push_frame_with_digest(f, digest);
            }
            if let Some((seq, d)) = own.as_ref().and_then(|m| m.sequence()).zip(digest)
                && s.fanout.answer_digests(seq, d) > 0
            {
                s.wake_all();
            }
            let keyframes = s.fanout.serve_keyframes();
            // Writers have something new only after a frame or a shared
            // keyframe; a still tick wakes no one.
            if frame.is_some() || keyframes == Keyframes::Shared {
                s.wake_all();
            }
            keyframes == Keyframes::Encode
        };
        if wants_keyframe {
            // One keyframe per state, shared by the clients that ask now
            // and those that ask before the next frame.
            match source.keyframe() {
                Ok(kf) => {
                    let wanted = hub.lock().fanout.wants_digest(true, None);
                    let digest = digest_after(&mut own, Some(&kf), wanted);
                    let mut s = hub.lock();
                    s.stats.keyframes += 1;
                    s.fanout.push_keyframe_with_digest(&kf, digest);
                    s.wake_all();
                }
                Err(e) => warn!("keyframe failed: {e}"),
            }
        }
        let now = Instant::now();
        if let Some(hz) = watch.tick(now) {
            let text = crate::rate::rate_text(hz, watch.rate());
            warn!("running below the announced frame rate: {text}");
            let mut s = hub.lock();
            if !s.clients.is_empty() {
                s.stats.rate_notices += 1;
                s.notice_all(NoticeCode::BelowRate, &text);
            }
        }
        let start = schedule.after_tick(now);
        trace!(
            step_ms = step_time.as_secs_f64() * 1e3,
            behind = schedule.behind_ticks(),
            lost = schedule.lost_ticks(),
            "tick"
        );
        {
            let mut s = hub.lock();
            s.stats.behind_ticks = schedule.behind_ticks();
            s.stats.lost_ticks = schedule.lost_ticks();
            s.stats.most_behind = schedule.most_behind();
        }
        // Until the next tick's start, whatever the time taken since.
        let wait = start.saturating_duration_since(Instant::now());
        if !wait.is_zero() {
            std::thread::sleep(wait);
        }
    }
    source
}

/// Applies `frame` (if any) to the server's mirror of its own stream, and
/// returns that mirror's digest when `wanted`. A frame the mirror refuses
/// (a source bug) is logged and leaves digests off until a keyframe
/// applies.
fn digest_after(
    own: &mut Option<OwnMirror>,
    frame: Option<&psao_codec::EncodedFrame>,
    wanted: bool,
) -> Option<u32> {
    let m = own.as_mut()?;
    if let Some(f) = frame
        && let Err(e) = m.apply(f)
    {
        warn!("{e}");
        return None;
    }
    if wanted { m.digest() } else { None }
}

pub(crate) async fn serve_connection<L: Link>(hub: Arc<Hub>, conn: L) {
    let remote = conn.remote_address();
    // A WebTransport session is closed with its own capsule on shutdown
    // (the connection's close would tell a page no code).
    let web = (L::BINDING == Binding::WebTransport).then(|| {
        let id = hub.next_web_session.fetch_add(1, Ordering::SeqCst);
        let c = conn.clone();
        let closer: SessionCloser = Box::new(move |code, reason| c.close(code, reason));
        lock_sessions(&hub).insert(id, closer);
        id
    });
    let result = run_connection(&hub, &conn).await;
    if let Some(id) = web {
        lock_sessions(&hub).remove(&id);
    }
    if let Err(e) = result {
        let close = Close::from(e);
        debug!(%remote, "closing: {close}");
        conn.close(close.code.code(), close.reason.as_bytes());
        // The session stays alive until the close went out: a WebTransport
        // one writes its close capsule from a task of its own, and dropping
        // it would stop its HTTP/3 streams first (a browser then sees a
        // lost connection, not the code).
        let _ = tokio::time::timeout(CLOSE_LINGER, conn.closed()).await;
    }
}

fn lock_sessions(hub: &Hub) -> MutexGuard<'_, HashMap<u64, SessionCloser>> {
    hub.web_sessions.lock().unwrap_or_else(|e| e.into_inner())
}

/// HTTP/3's `H3_NO_ERROR` (RFC 9114 8.1): how the WebTransport endpoint's
/// connections close on shutdown.
pub(crate) const H3_NO_ERROR: u32 = 0x100;

/// How long shutdown waits for WebTransport sessions' capsules to go out
/// before it closes their connections.
const WEB_CLOSE_WAIT: Duration = Duration::from_millis(300);

/// How long a closed session is kept for its close to go out.
const CLOSE_LINGER: Duration = Duration::from_secs(2);

/// Reads the control stream; registers the client after `HELLO`; the
/// writer task sends frames and notices.
async fn run_connection<L: Link>(hub: &Arc<Hub>, conn: &L) -> Result<(), SessionError> {
    let full = hub.lock().clients.len() >= hub.config.max_clients;
    if full {
        return Err(SessionError::ServerFull);
    }
    let mut session = ServerConn::new(hub.offer.clone(), Instant::now());
    let deadline = tokio::time::Instant::from_std(session.deadline().unwrap_or_else(Instant::now));
    let (send, mut recv) = tokio::select! {
        s = conn.accept_bi() => s.map_err(|e| SessionError::Ended(e.to_string().into()))?,
        _ = tokio::time::sleep_until(deadline) => {
            return Err(SessionError::HandshakeTimeout { awaited: "control stream" });
        }
    };
    // Violations found off the control stream (another stream opened, a
    // stream stopped, a keyframe above the client's limits) come to the
    // reader, which closes: control bytes received before them are read
    // first, so a violation in them wins and the close code of a given
    // misbehaviour does not depend on which task saw it first.
    let (ended, mut ends) = tokio::sync::mpsc::channel::<SessionError>(4);
    // Any other stream the client opens is a violation.
    let extra = {
        let (conn, ended) = (conn.clone(), ended.clone());
        tokio::spawn(async move {
            conn.any_stream().await;
            let _ = ended
                .send(SessionError::StreamMisused("a client opens one stream"))
                .await;
        })
    };
    let mut send = Some(send);
    let mut id = None;
    let mut buf = vec![0u8; 2048];
    let mut events = Vec::new();
    let result = 'read: loop {
        let deadline = session.deadline();
        let handshake = tokio::time::Instant::from_std(deadline.unwrap_or_else(Instant::now));
        // Biased: bytes already received are read before a violation
        // another task reported, or the handshake deadline, is acted on.
        let read = tokio::select! {
            biased;
            r = recv.read(&mut buf) => r,
            Some(e) = ends.recv() => break Err(e),
            _ = tokio::time::sleep_until(handshake), if deadline.is_some() => {
                break Err(SessionError::HandshakeTimeout { awaited: "HELLO" });
            }
        };
        let n = match read {
            Read::Data(n) => n,
            Read::Finished => {
                break Err(SessionError::StreamMisused(
                    "the client finished its control stream",
                ));
            }
            Read::Reset => {
                break Err(SessionError::StreamMisused(
                    "the client reset its control stream",
                ));
            }
            Read::Lost => break Ok(()),
        };
        if session.hello().is_none() {
            let (frame, payload) = hub.lock().fanout.largest();
            session.frames_so_far(frame, payload);
        }
        if let Err(close) = session.on_control(&buf[..n], Instant::now(), &mut events) {
            break Err(close);
        }
        for ev in events.drain(..) {
            match ev {
                ServerEvent::Welcomed { bytes, viewer } => {
                    let Some(mut control) = send.take() else {
                        continue;
                    };
                    if hub.lock().clients.len() >= hub.config.max_clients {
                        break 'read Err(SessionError::ServerFull);
                    }
                    if control.write_all(&bytes).await.is_err() {
                        break 'read Ok(());
                    }
                    // A client whose transport parameters allow no
                    // server-initiated stream would leave this waiting.
                    let frames = match tokio::time::timeout(FRAME_STREAM_WAIT, conn.open_uni())
                        .await
                    {
                        Ok(Ok(s)) => s,
                        Ok(Err(_)) => break 'read Ok(()),
                        Err(_) => {
                            break 'read Err(SessionError::StreamMisused(
                                "the client allows no frame stream (initial_max_streams_uni must be 1)",
                            ));
                        }
                    };
                    let wake = Arc::new(Notify::new());
                    let client = {
                        let mut s = hub.lock();
                        if s.clients.len() >= hub.config.max_clients {
                            break 'read Err(SessionError::ServerFull);
                        }
                        let client = s.fanout.add_client(viewer);
                        if let Some(h) = session.hello() {
                            s.fanout.set_limits(
                                client,
                                h.max_frame_bytes.min(hub.offer.max_frame_bytes),
                                h.max_payload_bytes.min(hub.offer.max_payload_bytes),
                            );
                            if h.digest && hub.offer.digest {
                                s.fanout.set_digests(client, hub.config.digest_interval);
                            }
                        }
                        s.stats.accepted += 1;
                        let udp = conn.clone();
                        s.clients.insert(
                            client,
                            Slot {
                                wake: wake.clone(),
                                frame_age: 0.0,
                                binding: L::BINDING,
                                frames: 0,
                                record_bytes: 0,
                                udp_sent: Arc::new(move || udp.udp_sent()),
                            },
                        );
                        client
                    };
                    id = Some(client);
                    info!(remote = %conn.remote_address(), client, "client joined");
                    hub.writers.fetch_add(1, Ordering::SeqCst);
                    let (h, conn, ended) = (hub.clone(), conn.clone(), ended.clone());
                    tokio::spawn(async move {
                        let end = write_loop(&h, client, wake, control, frames).await;
                        h.writers.fetch_sub(1, Ordering::SeqCst);
                        let error = match end {
                            // Shutting down: hold the streams until the
                            // connection closes, so that dropping them
                            // does not finish the control stream first.
                            WriterEnd::Shutdown(streams) => {
                                conn.closed().await;
                                drop(streams);
                                return;
                            }
                            // The reader removed the client: it closes the
                            // connection with its own reason.
                            WriterEnd::Left => return,
                            // A stream was stopped by the client.
                            WriterEnd::Stopped => {
                                SessionError::StreamMisused("a stream was stopped")
                            }
                            // Its keyframe is above its limits.
                            WriterEnd::Refused(reason) => SessionError::CapabilityMismatch(reason),
                        };
                        // The reader closes (it may have a violation of its
                        // own to report first); if it has gone, the
                        // connection is closed already.
                        let _ = ended.send(error).await;
                    });
                }
                ServerEvent::Ack(seq) => {
                    if let Some(c) = id {
                        let mut s = hub.lock();
                        let at = s.sent_at.iter().find(|(q, _)| *q == seq).map(|x| x.1);
                        if let (Some(at), Some(slot)) = (at, s.clients.get_mut(&c)) {
                            slot.frame_age = at.elapsed().as_secs_f64();
                        }
                    }
                }
                ServerEvent::DigestRequested { every } => {
                    if let Some(c) = id {
                        let mut s = hub.lock();
                        // A digest reads the whole mirror: a client may
                        // not ask for one every frame.
                        let every = if every == 0 {
                            0
                        } else {
                            every.max(MIN_DIGEST_EVERY)
                        };
                        s.fanout.set_digests(c, every);
                        s.fanout.request_digest(c);
                    }
                }
                ServerEvent::KeyframeRequested(_) => {
                    if let Some(c) = id {
                        hub.lock().fanout.request_keyframe(c);
                    }
                }
                ServerEvent::Move {
                    instance,
                    transform,
                } => {
                    let Some(c) = id else { continue };
                    let mut s = hub.lock();
                    if hub.config.allow_events {
                        s.moves.push((c, instance, transform));
                    } else {
                        s.notice(
                            c,
                            NoticeCode::EventRefused,
                            "this server does not accept scene events",
                        );
                    }
                }
                ServerEvent::Camera(pose) => {
                    if let Some(c) = id {
                        hub.lock().fanout.set_view(c, pose);
                    }
                }
            }
        }
    };
    extra.abort();
    if let Some(c) = id {
        let mut s = hub.lock();
        s.fanout.remove_client(c);
        if let Some(slot) = s.clients.remove(&c) {
            slot.wake.notify_one();
        }
        info!(client = c, "client left");
    }
    result
}

/// How a client's writer ended.
enum WriterEnd<S> {
    /// The client left (the reader removed it and closes the connection
    /// with its own reason).
    Left,
    /// A write failed: the client stopped or reset a stream.
    Stopped,
    /// The server shuts down: the streams, the frame stream finished, to
    /// be held until the connection closes.
    Shutdown((S, S)),
    /// The keyframe the client needs is above its limits: close with
    /// `capability_mismatch` and this reason.
    Refused(String),
}

/// Writes a client's notices and frames until it leaves, a write fails or
/// the server shuts down.
async fn write_loop<S: LinkSend>(
    hub: &Hub,
    client: ClientId,
    wake: Arc<Notify>,
    mut control: S,
    mut frames: S,
) -> WriterEnd<S> {
    loop {
        let Some(Transmit {
            notices,
            frame,
            refused,
        }) = hub.lock().fanout.poll_transmit(client)
        else {
            return WriterEnd::Left;
        };
        for n in notices {
            if control.write_all(&n).await.is_err() {
                return WriterEnd::Stopped;
            }
        }
        if let (None, Some(reason)) = (&frame, refused) {
            return WriterEnd::Refused(reason);
        }
        match frame {
            Some(f) => {
                let prefix = record_prefix(&f);
                if frames.write_all(&prefix).await.is_err() || frames.write_all(&f).await.is_err() {
                    return WriterEnd::Stopped;
                }
                let mut s = hub.lock();
                s.stats.written_bytes += 4 + f.len() as u64;
                if let Some(slot) = s.clients.get_mut(&client) {
                    slot.frames += 1;
                    slot.record_bytes += 4 + f.len() as u64;
                }
            }
            None if hub.closing.load(Ordering::SeqCst) => {
                // Shutting down and drained: end the frame stream after the
                // last whole record, and let the client acknowledge it.
                frames.finish();
                let _ = tokio::time::timeout(Duration::from_secs(1), frames.stopped()).await;
                return WriterEnd::Shutdown((control, frames));
            }
            None => wake.notified().await,
        }
    }
}
