//! The reference server: one scene, many clients, over QUIC (quinn and
//! tokio). The session logic is [`ServerConn`] and [`Outbox`]; this module
//! is the I/O around them.
//!
//! A pipeline thread steps the scene at the frame rate. Each frame is
//! encoded once; its bytes (shared, not copied) go into every in-sync
//! client's [`Outbox`]. A writer task per client drains its outbox onto the
//! client's frame stream. A client that cannot keep up falls behind (its
//! queued frames are dropped) and gets a keyframe once it has drained, so
//! a stalled client costs at most `max_queue_bytes` of deltas, one
//! keyframe, the frame being written, 16 notices and the QUIC send window.

use std::collections::{HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use bytes::Bytes;
use glam::Affine3A;
use psao_scene::{
    Camera, FrameReport, Pipeline, PipelineConfig, Scene, SceneError, ViewerCull, Views,
};
use tokio::sync::Notify;
use tracing::{debug, info, warn};

use crate::codes::{Close, CloseCode};
use crate::control::{CameraPose, NoticeCode};
use crate::outbox::Outbox;
use crate::records::record_prefix;
use crate::server_conn::{Offer, ServerConn, ServerEvent, notice};
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
    /// The scene pipeline.
    pub pipeline: PipelineConfig,
    /// The scene's name, sent in `WELCOME`.
    pub scene_name: String,
    /// A client silent this long (QUIC idle timeout) is dropped.
    pub idle_timeout: Duration,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            bind: SocketAddr::from(([127, 0, 0, 1], 0)),
            frame_rate: 60,
            max_clients: 256,
            max_queue_bytes: 1 << 20,
            allow_events: true,
            pipeline: PipelineConfig::default(),
            scene_name: "default".into(),
            idle_timeout: Duration::from_secs(10),
        }
    }
}

/// Errors starting a server.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The scene could not be prepared.
    #[error("scene: {0}")]
    Scene(#[from] SceneError),
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
    /// Clients connected now.
    pub clients: usize,
    /// Clients that completed a handshake since the start.
    pub accepted: u64,
    /// The last frame's sequence.
    pub sequence: u32,
    /// Sum of the per-frame reports.
    pub report: FrameReport,
    /// Time spent stepping the pipeline.
    pub step_time: Duration,
    /// Mean of the clients' last frame age (from a frame's send to its
    /// `ACK`), seconds.
    pub frame_age: f64,
    /// The largest bytes queued for one client right now.
    pub max_queued: usize,
}

struct Slot {
    outbox: Outbox,
    wake: Arc<Notify>,
    notices: Vec<Bytes>,
    /// Seconds from a frame's broadcast to the client's `ACK` of it.
    frame_age: f64,
    /// Whether its `HELLO` said it sends camera poses.
    viewer: bool,
    /// Its last `CAMERA`.
    view: Option<CameraPose>,
}

#[derive(Default)]
struct HubState {
    clients: HashMap<u64, Slot>,
    next_id: u64,
    moves: Vec<(u64, u32, Affine3A)>,
    stats: ServerStats,
    /// When recent sequences were broadcast.
    sent_at: VecDeque<(u32, Instant)>,
}

/// Most notices waiting for one client (the oldest are dropped).
const MAX_NOTICES: usize = 16;

struct Hub {
    state: Mutex<HubState>,
    /// The pipeline thread stops stepping.
    stop: AtomicBool,
    /// Writers finish their frame streams once drained (set after the
    /// pipeline's last frame was queued).
    closing: AtomicBool,
    /// Writer tasks still running.
    writers: std::sync::atomic::AtomicUsize,
    /// Wakes the pipeline thread when a client needs a keyframe.
    offer: Offer,
    config: ServerConfig,
}

impl Hub {
    fn lock(&self) -> MutexGuard<'_, HubState> {
        // A panic while holding the lock leaves counters only; go on.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Slot {
    /// Queues a notice, keeping at most [`MAX_NOTICES`].
    fn notice(&mut self, n: Bytes) {
        if self.notices.len() >= MAX_NOTICES {
            self.notices.remove(0);
        }
        self.notices.push(n);
        self.wake.notify_one();
    }
}

/// A running server.
pub struct ServerHandle {
    hub: Arc<Hub>,
    endpoint: quinn::Endpoint,
    addr: SocketAddr,
    fingerprint: [u8; 32],
    stepper: Option<std::thread::JoinHandle<Pipeline>>,
    acceptor: tokio::task::JoinHandle<()>,
}

impl std::fmt::Debug for ServerHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServerHandle")
            .field("addr", &self.addr)
            .finish()
    }
}

impl ServerHandle {
    /// Where it listens.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// SHA-256 of its certificate, for clients to pin.
    pub fn fingerprint(&self) -> [u8; 32] {
        self.fingerprint
    }

    /// Counters now.
    pub fn stats(&self) -> ServerStats {
        let s = self.hub.lock();
        let mut st = s.stats.clone();
        st.clients = s.clients.len();
        let ages: Vec<f64> = s.clients.values().map(|c| c.frame_age).collect();
        st.frame_age = ages.iter().sum::<f64>() / ages.len().max(1) as f64;
        st.max_queued = s
            .clients
            .values()
            .map(|c| c.outbox.queued_bytes())
            .max()
            .unwrap_or(0);
        st
    }

    /// Stops stepping, lets writers flush what is queued (at most
    /// `grace`), closes every connection with `server_shutdown` and
    /// returns the pipeline (its tables are what in-sync clients mirror)
    /// and the final counters.
    pub async fn shutdown(
        mut self,
        grace: Duration,
    ) -> Result<(Pipeline, ServerStats), ServeError> {
        self.acceptor.abort();
        self.hub.stop.store(true, Ordering::SeqCst);
        let stepper = self.stepper.take();
        let pipeline = tokio::task::spawn_blocking(move || stepper.map(|h| h.join()))
            .await
            .ok()
            .flatten()
            .and_then(|r| r.ok());
        // The last frame is queued: writers drain their outboxes, finish
        // their frame streams and wait (up to 1 s) for the client to
        // acknowledge them.
        self.hub.closing.store(true, Ordering::SeqCst);
        for c in self.hub.lock().clients.values() {
            c.wake.notify_one();
        }
        let until = Instant::now() + grace;
        while Instant::now() < until && self.hub.writers.load(Ordering::SeqCst) > 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let stats = self.stats();
        self.endpoint.close(
            quinn::VarInt::from_u32(CloseCode::ServerShutdown.code()),
            b"server shutdown",
        );
        self.endpoint.wait_idle().await;
        let pipeline =
            pipeline.ok_or(ServeError::Stopped("the pipeline thread panicked".into()))?;
        Ok((pipeline, stats))
    }
}

impl Drop for ServerHandle {
    /// A handle dropped without [`shutdown`](ServerHandle::shutdown) still
    /// stops the server: stepping ends, the listener goes and every
    /// connection is closed with `server_shutdown`.
    fn drop(&mut self) {
        self.hub.stop.store(true, Ordering::SeqCst);
        self.hub.closing.store(true, Ordering::SeqCst);
        self.acceptor.abort();
        self.endpoint.close(
            quinn::VarInt::from_u32(CloseCode::ServerShutdown.code()),
            b"server shutdown",
        );
    }
}

/// Starts a server streaming `scene`.
pub async fn serve(
    scene: Scene,
    config: ServerConfig,
    identity: &Identity,
) -> Result<ServerHandle, ServeError> {
    if config.frame_rate == 0 || config.frame_rate > 1000 {
        return Err(ServeError::Setting("frame_rate (1..=1000)"));
    }
    if config.max_queue_bytes < 1024 {
        return Err(ServeError::Setting("max_queue_bytes (at least 1024)"));
    }
    let pipeline = Pipeline::new(scene, config.pipeline.clone())?;
    let enc = pipeline.config().encoder;
    let mirror_bytes = (0..pipeline.instance_count())
        .filter_map(|i| pipeline.table(i))
        .map(|t| t.def().mirror_bytes() as u64)
        .sum();
    let offer = Offer {
        compression: enc.compression.id(),
        max_frame_bytes: enc.limits.max_frame_bytes,
        max_payload_bytes: enc.limits.max_payload_bytes,
        mirror_bytes,
        frame_rate: config.frame_rate,
        scene: config.scene_name.clone(),
        culling: config.pipeline.cull.is_some(),
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
        state: Mutex::new(HubState::default()),
        stop: AtomicBool::new(false),
        closing: AtomicBool::new(false),
        writers: std::sync::atomic::AtomicUsize::new(0),
        offer,
        config,
    });
    let stepper = {
        let hub = hub.clone();
        std::thread::Builder::new()
            .name("psao-pipeline".into())
            .spawn(move || step_loop(pipeline, &hub))
            .map_err(|e| ServeError::Bind {
                addr,
                reason: format!("cannot start the pipeline thread: {e}"),
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
    })
}

/// What a culling server culls to (spec/session.md 3.2): the union of its
/// clients' views. While a client that does not say what it sees (not a
/// viewer, or no `CAMERA` yet) is connected, nothing is culled; with no
/// client, no one looks and every point waits.
fn views(state: &HubState, cull: &ViewerCull) -> Views {
    let mut frusta = Vec::with_capacity(state.clients.len());
    for slot in state.clients.values() {
        let Some(pose) = slot.view.filter(|_| slot.viewer) else {
            return Views::All;
        };
        let camera = Camera {
            eye: pose.eye,
            target: pose.target,
            fov_y: pose.fov_y,
        };
        frusta.push(camera.frustum(pose.aspect, cull.near(), cull.far));
    }
    Views::Frusta(frusta)
}

/// The pipeline thread: step, broadcast, keyframes; returns the pipeline
/// when told to stop.
fn step_loop(mut pipeline: Pipeline, hub: &Hub) -> Pipeline {
    let dt = 1.0 / hub.config.frame_rate as f32;
    let period = Duration::from_secs_f64(1.0 / hub.config.frame_rate as f64);
    let mut next = Instant::now() + period;
    let mut cached_keyframe: Option<(u32, Bytes)> = None;
    let mut last_sequence: Option<u32> = None;
    while !hub.stop.load(Ordering::SeqCst) {
        // Scene events first, so the frame carries them.
        let moves = std::mem::take(&mut hub.lock().moves);
        for (client, instance, t) in moves {
            if let Err(e) = pipeline.place_instance(instance as usize, t) {
                let n = notice(NoticeCode::EventRefused, &e.to_string());
                if let Some(c) = hub.lock().clients.get_mut(&client) {
                    c.notice(n);
                }
            }
        }
        if let Some(cull) = hub.config.pipeline.cull {
            pipeline.set_views(views(&hub.lock(), &cull));
        }
        let t0 = Instant::now();
        let stepped = pipeline.step(dt);
        let step_time = t0.elapsed();
        let (frame, report) = match stepped {
            Ok(x) => x,
            Err(e) => {
                warn!("pipeline step failed: {e}");
                (None, FrameReport::default())
            }
        };
        let wants_keyframe = {
            let mut s = hub.lock();
            s.stats.frames += 1;
            s.stats.step_time += step_time;
            s.stats.report.accumulate(&report);
            if let Some(f) = &frame {
                last_sequence = Some(f.sequence);
                s.stats.sent_frames += 1;
                s.stats.encoded_bytes += f.bytes.len() as u64;
                s.stats.sequence = f.sequence;
                s.sent_at.push_back((f.sequence, Instant::now()));
                if s.sent_at.len() > 512 {
                    s.sent_at.pop_front();
                }
                let mut falls = 0;
                for c in s.clients.values_mut() {
                    if c.outbox.push_delta(f.bytes.clone()) == crate::outbox::Pushed::FellBehind {
                        falls += 1;
                    }
                    c.wake.notify_one();
                }
                s.stats.falls += falls;
            }
            s.clients.values().any(|c| c.outbox.wants_keyframe())
        };
        if wants_keyframe {
            // One keyframe per state: clients asking at the same sequence
            // share it, however many ask or how often.
            let cached = cached_keyframe
                .as_ref()
                .filter(|(seq, _)| frame.is_none() && Some(*seq) == last_sequence)
                .map(|(_, b)| b.clone());
            let kf = match cached {
                Some(b) => Ok(b),
                None => pipeline.keyframe().map(|kf| {
                    hub.lock().stats.keyframes += 1;
                    last_sequence = Some(kf.sequence);
                    cached_keyframe = Some((kf.sequence, kf.bytes.clone()));
                    kf.bytes
                }),
            };
            match kf {
                Ok(kf) => {
                    let mut s = hub.lock();
                    for c in s.clients.values_mut() {
                        if c.outbox.wants_keyframe() {
                            if c.outbox.push_keyframe(kf.clone()) {
                                c.notice(notice(
                                    NoticeCode::FellBehind,
                                    "fell behind; resynchronizing with a keyframe",
                                ));
                            }
                            c.wake.notify_one();
                        }
                    }
                }
                Err(e) => warn!("keyframe failed: {e}"),
            }
        }
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
            next += period;
        } else {
            // Running late: do not try to catch up in a burst.
            next = now + period;
        }
    }
    pipeline
}

async fn serve_connection(hub: Arc<Hub>, conn: quinn::Connection) {
    let remote = conn.remote_address();
    let result = run_connection(&hub, &conn).await;
    if let Err(close) = &result {
        debug!(%remote, "closing: {close}");
        conn.close(
            quinn::VarInt::from_u32(close.code.code()),
            close.reason.as_bytes(),
        );
    }
}

/// Reads the control stream; registers the client after `HELLO`; the
/// writer task sends frames and notices.
async fn run_connection(hub: &Arc<Hub>, conn: &quinn::Connection) -> Result<(), Close> {
    let full = hub.lock().clients.len() >= hub.config.max_clients;
    if full {
        return Err(Close::new(CloseCode::ServerFull, "server full"));
    }
    let mut session = ServerConn::new(hub.offer.clone(), Instant::now());
    let deadline = tokio::time::Instant::from_std(session.deadline().unwrap_or_else(Instant::now));
    let (send, mut recv) = tokio::select! {
        s = conn.accept_bi() => s.map_err(|e| Close::new(CloseCode::NoError, e.to_string()))?,
        _ = tokio::time::sleep_until(deadline) => {
            return Err(Close::new(CloseCode::HandshakeTimeout, "no control stream within 5 s"));
        }
    };
    // Any other stream the client opens is a violation.
    let extra = {
        let conn = conn.clone();
        tokio::spawn(async move {
            tokio::select! {
                _ = conn.accept_uni() => {}
                _ = conn.accept_bi() => {}
            }
            conn.close(
                quinn::VarInt::from_u32(CloseCode::ProtocolViolation.code()),
                b"a client opens one stream",
            );
        })
    };
    let mut send = Some(send);
    let mut id = None;
    let mut buf = vec![0u8; 2048];
    let mut events = Vec::new();
    let result = 'read: loop {
        let read = match session.deadline() {
            Some(d) => tokio::select! {
                r = recv.read(&mut buf) => r,
                _ = tokio::time::sleep_until(tokio::time::Instant::from_std(d)) => {
                    break Err(Close::new(CloseCode::HandshakeTimeout, "no HELLO within 5 s"));
                }
            },
            None => recv.read(&mut buf).await,
        };
        let n = match read {
            Ok(Some(n)) => n,
            Ok(None) => {
                break Err(Close::new(
                    CloseCode::ProtocolViolation,
                    "the client finished its control stream",
                ));
            }
            Err(quinn::ReadError::Reset(_)) => {
                break Err(Close::new(
                    CloseCode::ProtocolViolation,
                    "the client reset its control stream",
                ));
            }
            Err(_) => break Ok(()),
        };
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
                        break 'read Err(Close::new(CloseCode::ServerFull, "server full"));
                    }
                    if control.write_all(&bytes).await.is_err() {
                        break 'read Ok(());
                    }
                    let frames = match conn.open_uni().await {
                        Ok(s) => s,
                        Err(_) => break 'read Ok(()),
                    };
                    let wake = Arc::new(Notify::new());
                    let client = {
                        let mut s = hub.lock();
                        if s.clients.len() >= hub.config.max_clients {
                            break 'read Err(Close::new(CloseCode::ServerFull, "server full"));
                        }
                        let client = s.next_id;
                        s.next_id += 1;
                        s.stats.accepted += 1;
                        s.clients.insert(
                            client,
                            Slot {
                                outbox: Outbox::new(hub.config.max_queue_bytes),
                                wake: wake.clone(),
                                notices: Vec::new(),
                                frame_age: 0.0,
                                viewer,
                                view: None,
                            },
                        );
                        client
                    };
                    id = Some(client);
                    info!(remote = %conn.remote_address(), client, "client joined");
                    hub.writers.fetch_add(1, Ordering::SeqCst);
                    let (h, conn) = (hub.clone(), conn.clone());
                    tokio::spawn(async move {
                        let streams = write_loop(&h, client, wake, control, frames).await;
                        h.writers.fetch_sub(1, Ordering::SeqCst);
                        match streams {
                            // Shutting down: hold the streams until the
                            // connection closes, so that dropping them
                            // does not finish the control stream first.
                            Some(streams) => {
                                conn.closed().await;
                                drop(streams);
                            }
                            // A stream was stopped or reset by the client.
                            None => conn.close(
                                quinn::VarInt::from_u32(CloseCode::ProtocolViolation.code()),
                                b"a stream was stopped",
                            ),
                        }
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
                ServerEvent::KeyframeRequested(_) => {
                    if let Some(c) = id
                        && let Some(slot) = hub.lock().clients.get_mut(&c)
                    {
                        slot.outbox.request_keyframe();
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
                    } else if let Some(slot) = s.clients.get_mut(&c) {
                        slot.notice(notice(
                            NoticeCode::EventRefused,
                            "this server does not accept scene events",
                        ));
                    }
                }
                ServerEvent::Camera(pose) => {
                    if let Some(c) = id
                        && let Some(slot) = hub.lock().clients.get_mut(&c)
                    {
                        slot.view = Some(pose);
                    }
                }
            }
        }
    };
    extra.abort();
    if let Some(c) = id {
        let mut s = hub.lock();
        if let Some(slot) = s.clients.remove(&c) {
            slot.wake.notify_one();
        }
        info!(client = c, "client left");
    }
    result
}

/// Writes a client's notices and frames until it leaves (`None`, also
/// when a write fails) or the server shuts down (the streams, the frame
/// stream finished, to be held until the connection closes).
async fn write_loop(
    hub: &Hub,
    client: u64,
    wake: Arc<Notify>,
    mut control: quinn::SendStream,
    mut frames: quinn::SendStream,
) -> Option<(quinn::SendStream, quinn::SendStream)> {
    loop {
        let (notices, frame) = {
            let mut s = hub.lock();
            let slot = s.clients.get_mut(&client)?;
            (std::mem::take(&mut slot.notices), slot.outbox.pop())
        };
        for n in notices {
            control.write_all(&n).await.ok()?;
        }
        match frame {
            Some(f) => {
                let prefix = record_prefix(&f);
                frames.write_all(&prefix).await.ok()?;
                frames.write_all(&f).await.ok()?;
                hub.lock().stats.written_bytes += 4 + f.len() as u64;
            }
            None if hub.closing.load(Ordering::SeqCst) => {
                // Shutting down and drained: end the frame stream after the
                // last whole record, and let the client acknowledge it.
                let _ = frames.finish();
                let _ = tokio::time::timeout(Duration::from_secs(1), frames.stopped()).await;
                return Some((control, frames));
            }
            None => wake.notified().await,
        }
    }
}
