//! The reference client over QUIC: connects, negotiates, and keeps a
//! [`ClientSession`] (and its mirror) in sync in a background task. The
//! renderer reads the mirror through [`ClientHandle::with_session`].

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use bytes::Bytes;
use tokio::sync::{Notify, mpsc};

use crate::client::{ClientConfig, ClientSession};
use crate::codes::{Close, CloseCode, SessionError};
use crate::control::CameraPose;
use crate::tls::{TlsError, Trust, client_config};

/// Errors connecting.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConnectError {
    /// TLS setup failed.
    #[error(transparent)]
    Tls(#[from] TlsError),
    /// The connection could not be made.
    #[error("cannot connect to {addr}: {reason}")]
    Connect {
        /// The server.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
    /// The server closed the session.
    #[error("the server closed the session: {0}")]
    Closed(Close),
    /// No `WELCOME` within the timeout.
    #[error("no WELCOME within {0:?}")]
    Timeout(Duration),
}

/// How a session ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ended {
    /// Still running.
    Running,
    /// Closed with this code and reason (by either side).
    Closed(Close),
}

/// Most bytes of captured frames held for [`ClientHandle::take_captured`].
pub const MAX_CAPTURED_BYTES: usize = 64 << 20;

#[derive(Default)]
struct Captured {
    frames: Vec<(std::time::Instant, Bytes)>,
    bytes: usize,
    dropped: u64,
}

struct Shared {
    session: Mutex<ClientSession>,
    captured: Mutex<Captured>,
    ended: Mutex<Ended>,
    changed: Notify,
}

/// A connected client.
pub struct ClientHandle {
    shared: Arc<Shared>,
    conn: quinn::Connection,
    endpoint: quinn::Endpoint,
    uplink: mpsc::UnboundedSender<Uplink>,
    task: tokio::task::JoinHandle<()>,
}

impl std::fmt::Debug for ClientHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientHandle")
            .field("remote", &self.conn.remote_address())
            .finish()
    }
}

enum Uplink {
    Camera(CameraPose),
    Move(u32, glam::Affine3A),
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Connects to `addr`, trusting it as `trust` says, and waits for
/// `WELCOME` (at most `timeout`).
pub async fn connect(
    addr: SocketAddr,
    trust: &Trust,
    config: ClientConfig,
    timeout: Duration,
) -> Result<ClientHandle, ConnectError> {
    let bind: SocketAddr = if addr.is_ipv6() {
        "[::]:0".parse().expect("an address")
    } else {
        "0.0.0.0:0".parse().expect("an address")
    };
    let mut endpoint = quinn::Endpoint::client(bind).map_err(|e| ConnectError::Connect {
        addr,
        reason: e.to_string(),
    })?;
    endpoint.set_default_client_config(client_config(trust)?);
    let fail = |reason: String| ConnectError::Connect { addr, reason };
    let conn = endpoint
        .connect(addr, trust.server_name())
        .map_err(|e| fail(e.to_string()))?
        .await
        .map_err(|e| connection_error(e, addr))?;
    let (send, recv) = conn
        .open_bi()
        .await
        .map_err(|e| connection_error(e, addr))?;
    let shared = Arc::new(Shared {
        session: Mutex::new(ClientSession::new(config)),
        captured: Mutex::new(Captured::default()),
        ended: Mutex::new(Ended::Running),
        changed: Notify::new(),
    });
    let (uplink, rx) = mpsc::unbounded_channel();
    let task = tokio::spawn(run(shared.clone(), conn.clone(), send, recv, rx));
    let handle = ClientHandle {
        shared,
        conn,
        endpoint,
        uplink,
        task,
    };
    let waited = tokio::time::timeout(timeout, async {
        loop {
            let notified = handle.shared.changed.notified();
            if handle.with_session(|s| s.welcome().is_some()) {
                return Ok(());
            }
            if let Ended::Closed(c) = handle.ended() {
                return Err(ConnectError::Closed(c));
            }
            notified.await;
        }
    })
    .await;
    match waited {
        Ok(Ok(())) => Ok(handle),
        Ok(Err(e)) => Err(e),
        Err(_) => Err(ConnectError::Timeout(timeout)),
    }
}

fn connection_error(e: quinn::ConnectionError, addr: SocketAddr) -> ConnectError {
    match e {
        quinn::ConnectionError::ApplicationClosed(c) => ConnectError::Closed(close_of(&c)),
        quinn::ConnectionError::ConnectionClosed(c)
            if c.error_code == quinn::TransportErrorCode::CONNECTION_REFUSED =>
        {
            ConnectError::Closed(Close::new(CloseCode::ServerFull, "connection refused"))
        }
        e => ConnectError::Connect {
            addr,
            reason: e.to_string(),
        },
    }
}

/// How a closed connection reads as a session close (spec/session.md 7:
/// transport errors and idle timeouts count as `internal_error`).
fn close_of_error(e: quinn::ConnectionError) -> Close {
    match e {
        quinn::ConnectionError::ApplicationClosed(c) => close_of(&c),
        quinn::ConnectionError::LocallyClosed => Close::new(CloseCode::NoError, "closed here"),
        quinn::ConnectionError::ConnectionClosed(c)
            if c.error_code == quinn::TransportErrorCode::CONNECTION_REFUSED =>
        {
            Close::new(CloseCode::ServerFull, "connection refused")
        }
        e => Close::new(CloseCode::InternalError, e.to_string()),
    }
}

/// How a session that ended with the connection's `reason` reads: a close
/// from either side is that close; any other end (a timeout, a reset) is
/// what [`ClientSession::transport_lost`] says, which knows whether the
/// server had finished the frame stream (spec/session.md 5.3).
fn close_after(reason: quinn::ConnectionError, session: &ClientSession) -> Close {
    match reason {
        quinn::ConnectionError::ApplicationClosed(_) | quinn::ConnectionError::LocallyClosed => {
            close_of_error(reason)
        }
        e if session.frames_finished() => session.transport_lost(&e.to_string()).into(),
        e => close_of_error(e),
    }
}

fn close_of(c: &quinn::ApplicationClose) -> Close {
    Close::new(
        CloseCode::from_code(c.error_code.into_inner()),
        String::from_utf8_lossy(&c.reason).into_owned(),
    )
}

async fn run(
    shared: Arc<Shared>,
    conn: quinn::Connection,
    mut send: quinn::SendStream,
    mut recv: quinn::RecvStream,
    mut uplink: mpsc::UnboundedReceiver<Uplink>,
) {
    let mut frames: Option<quinn::RecvStream> = None;
    let mut cbuf = vec![0u8; 4096];
    let mut fbuf = vec![0u8; 64 * 1024];
    let outcome: Result<(), SessionError> = async {
        loop {
            // Time first: the session repeats an unanswered keyframe
            // request and ends itself when a close never followed the
            // finished frame stream; it says when it next needs waking.
            // The server finishes the frame stream when it shuts down; the
            // connection close follows, and the stream is read no more.
            let (wake, frames_done) = {
                let mut s = lock(&shared.session);
                s.handle_timeout(std::time::Instant::now())?;
                (s.poll_timeout(), s.frames_finished())
            };
            // Send what the session queued (HELLO first, then ACKs and
            // keyframe requests).
            let out: Option<Bytes> = lock(&shared.session).take_transmit();
            if let Some(b) = out {
                send.write_all(&b)
                    .await
                    .map_err(|e| SessionError::Ended(e.to_string().into()))?;
            }
            tokio::select! {
                r = recv.read(&mut cbuf) => {
                    match r {
                        Ok(Some(n)) => lock(&shared.session).on_control(&cbuf[..n])?,
                        Ok(None) => return Err(SessionError::StreamMisused("the server finished the control stream")),
                        Err(quinn::ReadError::Reset(_)) => return Err(SessionError::StreamMisused("the server reset the control stream")),
                        Err(e) => return Err(SessionError::Transport(e.to_string())),
                    }
                }
                s = conn.accept_uni(), if frames.is_none() => {
                    frames = Some(s.map_err(|e| SessionError::Ended(e.to_string().into()))?);
                }
                r = async { frames.as_mut().expect("guarded").read(&mut fbuf).await }, if frames.is_some() && !frames_done => {
                    match r {
                        Ok(Some(n)) => {
                            let got = {
                                let mut s = lock(&shared.session);
                                s.on_frames(&fbuf[..n])?;
                                s.take_captured()
                            };
                            if !got.is_empty() {
                                let now = std::time::Instant::now();
                                let mut c = lock(&shared.captured);
                                for f in got {
                                    if c.bytes + f.len() > MAX_CAPTURED_BYTES {
                                        c.dropped += 1;
                                        continue;
                                    }
                                    c.bytes += f.len();
                                    c.frames.push((now, f));
                                }
                            }
                        }
                        Ok(None) => lock(&shared.session).on_frames_finished(std::time::Instant::now()),
                        Err(quinn::ReadError::Reset(_)) => return Err(SessionError::StreamMisused("the server reset the frame stream")),
                        Err(e) => return Err(SessionError::Transport(e.to_string())),
                    }
                }
                _ = async { tokio::time::sleep_until(tokio::time::Instant::from_std(wake.expect("guarded"))).await }, if wake.is_some() => {}
                u = uplink.recv() => {
                    let mut s = lock(&shared.session);
                    match u {
                        Some(Uplink::Camera(c)) => { s.send_camera(c); }
                        Some(Uplink::Move(i, t)) => s.send_move(i, t),
                        // The handle is gone: end the session.
                        None => return Err(SessionError::Ended("client dropped".into())),
                    }
                }
            }
            shared.changed.notify_waiters();
        }
    }
    .await;
    // The connection may already be closed (by the server, or lost): its
    // reason wins; otherwise close it with ours.
    let ended = match conn.close_reason() {
        Some(e) => close_after(e, &lock(&shared.session)),
        None => {
            let close = match outcome {
                Err(e) => Close::from(e),
                Ok(()) => Close::new(CloseCode::NoError, "bye"),
            };
            // A close the server meant but never delivered is ours to
            // finish, without blaming it on the wire.
            let code = if close.code == CloseCode::ServerShutdown {
                CloseCode::NoError
            } else {
                close.code
            };
            conn.close(
                quinn::VarInt::from_u32(code.code()),
                close.reason.as_bytes(),
            );
            close
        }
    };
    *lock(&shared.ended) = Ended::Closed(ended);
    shared.changed.notify_waiters();
}

impl ClientHandle {
    /// Runs `f` on the session (its mirror, events and counters). Keep it
    /// short: frames wait while it runs.
    pub fn with_session<R>(&self, f: impl FnOnce(&mut ClientSession) -> R) -> R {
        f(&mut lock(&self.shared.session))
    }

    /// How the session stands.
    pub fn ended(&self) -> Ended {
        lock(&self.shared.ended).clone()
    }

    /// Waits until `f` holds on the session or it ends, at most `timeout`;
    /// returns whether `f` held.
    pub async fn wait_for(
        &self,
        timeout: Duration,
        mut f: impl FnMut(&mut ClientSession) -> bool,
    ) -> bool {
        tokio::time::timeout(timeout, async {
            loop {
                let notified = self.shared.changed.notified();
                if self.with_session(&mut f) {
                    return true;
                }
                if self.ended() != Ended::Running {
                    return false;
                }
                notified.await;
            }
        })
        .await
        .unwrap_or(false)
    }

    /// Frames received since the last call, with their arrival times (a
    /// client made with `capture` set), and how many were dropped because
    /// more than [`MAX_CAPTURED_BYTES`] waited.
    pub fn take_captured(&self) -> (Vec<(std::time::Instant, Bytes)>, u64) {
        let mut c = lock(&self.shared.captured);
        c.bytes = 0;
        (
            std::mem::take(&mut c.frames),
            std::mem::take(&mut c.dropped),
        )
    }

    /// Sends the camera pose (a viewer client).
    pub fn send_camera(&self, pose: CameraPose) {
        let _ = self.uplink.send(Uplink::Camera(pose));
    }

    /// Asks the server to place an instance.
    pub fn send_move(&self, instance: u32, transform: glam::Affine3A) {
        let _ = self.uplink.send(Uplink::Move(instance, transform));
    }

    /// The round-trip time QUIC measures.
    pub fn rtt(&self) -> Duration {
        self.conn.rtt()
    }

    /// Closes the session (`no_error`) and waits for the endpoint to go
    /// idle.
    pub async fn close(self) {
        self.conn.close(quinn::VarInt::from_u32(0), b"bye");
        self.task.abort();
        self.endpoint.wait_idle().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session whose frame stream finished (`done`) or not.
    fn session(done: bool) -> ClientSession {
        let mut s = ClientSession::new(ClientConfig::default());
        if done {
            s.on_frames_finished(std::time::Instant::now());
        }
        s
    }

    #[test]
    fn a_lost_close_after_the_frame_stream_finished_is_a_server_shutdown() {
        let shut = close_after(quinn::ConnectionError::TimedOut, &session(true));
        assert_eq!(shut.code, CloseCode::ServerShutdown, "{shut}");
        let reset = close_after(quinn::ConnectionError::Reset, &session(true));
        assert_eq!(reset.code, CloseCode::ServerShutdown, "{reset}");
        // Before the frame stream finished, it is what it says.
        let lost = close_after(quinn::ConnectionError::TimedOut, &session(false));
        assert_eq!(lost.code, CloseCode::InternalError, "{lost}");
        // A close that arrived keeps its code either way.
        let full = quinn::ConnectionError::ApplicationClosed(quinn::ApplicationClose {
            error_code: quinn::VarInt::from_u32(CloseCode::ServerFull.code()),
            reason: Bytes::from_static(b"full"),
        });
        assert_eq!(
            close_after(full, &session(true)).code,
            CloseCode::ServerFull
        );
        let here = close_after(quinn::ConnectionError::LocallyClosed, &session(true));
        assert_eq!(here.code, CloseCode::NoError);
    }
}
