//! A bare QUIC client for probing a server: it sends whatever bytes a
//! case wants on the control stream, reads what comes back message by
//! message and record by record, and reports how the connection closed.
//! Every wait is bounded; failures are strings a report can print.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use psao_codec::wire::FrameHeader;
use psao_codec::{Decoder, Limits};
use psao_proto::control::{Control, ControlReader, Hello, Sender, Welcome};
use psao_proto::tls::client_config;
use psao_proto::{CloseCode, Trust};

/// A server to probe.
#[derive(Clone, Debug)]
pub struct Target {
    /// Its address.
    pub addr: SocketAddr,
    /// How to trust its certificate.
    pub trust: Trust,
    /// The server name to connect to (SNI).
    pub server_name: String,
}

/// How a connection ended, as a probe saw it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The server closed it with an application code and reason.
    Closed(CloseCode, String),
    /// Something else: a transport error, a timeout, our own close.
    Other(String),
}

impl std::fmt::Display for Ended {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Ended::Closed(code, reason) => write!(f, "closed with {} (\"{reason}\")", code.name()),
            Ended::Other(what) => f.write_str(what),
        }
    }
}

/// Control messages read off a receiving stream one at a time, holding
/// at most one message and one read chunk.
pub struct ControlIn {
    recv: quinn::RecvStream,
    reader: ControlReader,
    buf: Vec<u8>,
    /// Who sends them, for messages: "the server", "the client".
    peer: &'static str,
}

impl ControlIn {
    /// Reads `from`'s messages off `recv` (`peer` names it in errors).
    pub fn new(recv: quinn::RecvStream, from: Sender, peer: &'static str) -> ControlIn {
        ControlIn {
            recv,
            reader: ControlReader::from(from),
            buf: Vec::new(),
            peer,
        }
    }

    /// The next message within `wait`; `Ok(None)` when none came in
    /// time. A malformed message or the stream ending is an error naming
    /// it.
    pub async fn next(&mut self, wait: Duration) -> Result<Option<Control>, String> {
        let deadline = tokio::time::Instant::now() + wait;
        loop {
            let mut input = &self.buf[..];
            let got = self.reader.read(&mut input);
            let used = self.buf.len() - input.len();
            self.buf.drain(..used);
            match got {
                Ok(Some(m)) => return Ok(Some(m)),
                Ok(None) => {}
                Err(e) => {
                    return Err(format!(
                        "{} sent a malformed control message: {e}",
                        self.peer
                    ));
                }
            }
            let mut chunk = [0u8; 2048];
            match tokio::time::timeout_at(deadline, self.recv.read(&mut chunk)).await {
                Err(_) => return Ok(None),
                Ok(Ok(Some(n))) => self.buf.extend_from_slice(&chunk[..n]),
                Ok(Ok(None)) => return Err(format!("{} finished its control stream", self.peer)),
                Ok(Err(e)) => return Err(format!("{}'s control stream ended: {e}", self.peer)),
            }
        }
    }
}

/// One probing connection: its control stream and, once the server opened
/// it, the frame stream, with a mirror fed from it.
pub struct Probe {
    _endpoint: quinn::Endpoint,
    /// The connection.
    pub conn: quinn::Connection,
    /// The control stream's sending half.
    pub send: quinn::SendStream,
    control: ControlIn,
    frames: Option<quinn::RecvStream>,
    /// A mirror of what the frame stream carried.
    pub decoder: Decoder,
    /// (sequence, keyframe) of every frame read.
    pub seen: Vec<(u32, bool)>,
    /// When set, the mirror's digest after each frame read is kept here
    /// (the last 256), to check a `DIGEST` that arrives after its frame.
    pub digests: Option<std::collections::VecDeque<(u32, Option<u32>)>>,
}

/// The largest frame a probe reads (the limits its HELLOs offer at most).
const MAX_FRAME: u32 = 64 << 20;

impl Probe {
    /// Connects and opens the control stream (nothing is sent yet).
    pub async fn connect(target: &Target) -> Result<Probe, String> {
        let mut endpoint = quinn::Endpoint::client(if target.addr.is_ipv6() {
            "[::]:0".parse().expect("address")
        } else {
            "0.0.0.0:0".parse().expect("address")
        })
        .map_err(|e| format!("cannot open a UDP socket: {e}"))?;
        let mut cc = client_config(&target.trust).map_err(|e| e.to_string())?;
        let mut transport = quinn::TransportConfig::default();
        transport.max_concurrent_bidi_streams(0u32.into());
        transport.max_concurrent_uni_streams(1u32.into());
        transport.keep_alive_interval(Some(Duration::from_secs(1)));
        cc.transport_config(Arc::new(transport));
        endpoint.set_default_client_config(cc);
        let connecting = endpoint
            .connect(target.addr, &target.server_name)
            .map_err(|e| format!("cannot connect: {e}"))?;
        let conn = tokio::time::timeout(Duration::from_secs(10), connecting)
            .await
            .map_err(|_| "the QUIC handshake took over 10 s".to_string())?
            .map_err(|e| format!("the QUIC handshake failed: {e}"))?;
        let (send, recv) = conn
            .open_bi()
            .await
            .map_err(|e| format!("cannot open the control stream: {e}"))?;
        Ok(Probe {
            _endpoint: endpoint,
            conn,
            send,
            control: ControlIn::new(recv, Sender::Server, "the server"),
            frames: None,
            decoder: Decoder::new(Limits {
                max_frame_bytes: MAX_FRAME,
                max_payload_bytes: MAX_FRAME,
                ..Limits::default()
            }),
            seen: Vec::new(),
            digests: None,
        })
    }

    /// Writes raw bytes on the control stream.
    pub async fn write(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.send
            .write_all(bytes)
            .await
            .map_err(|e| format!("cannot write on the control stream: {e}"))
    }

    /// Sends a control message.
    pub async fn send(&mut self, msg: Control) -> Result<(), String> {
        self.write(&msg.to_bytes()).await
    }

    /// The next control message from the server within `wait`; `Ok(None)`
    /// when none came in time. A malformed message or the stream ending is
    /// an error naming it.
    pub async fn next_control(&mut self, wait: Duration) -> Result<Option<Control>, String> {
        self.control.next(wait).await
    }

    /// Sends `hello` and reads the answer, which must be `WELCOME`.
    pub async fn hello(&mut self, hello: Hello) -> Result<Welcome, String> {
        self.send(Control::Hello(hello)).await?;
        match self.next_control(Duration::from_secs(10)).await {
            Ok(Some(Control::Welcome(w))) => Ok(w),
            Ok(Some(other)) => Err(format!("the first message was {other:?}, not WELCOME")),
            Ok(None) => Err("no WELCOME within 10 s".into()),
            Err(e) => Err(match self.ended(Duration::from_millis(200)).await {
                Ended::Closed(code, reason) => {
                    format!("no WELCOME: closed with {} (\"{reason}\")", code.name())
                }
                Ended::Other(_) => e,
            }),
        }
    }

    /// Reads frame records for `time` (accepting the frame stream first),
    /// applying each to the probe's mirror; returns how many were read.
    /// Records are read whole; the wait is checked between them.
    pub async fn read_frames(&mut self, time: Duration) -> Result<usize, String> {
        let deadline = tokio::time::Instant::now() + time;
        if self.frames.is_none() {
            let s = tokio::time::timeout_at(deadline, self.conn.accept_uni())
                .await
                .map_err(|_| "the server opened no frame stream".to_string())?
                .map_err(|e| format!("no frame stream: {e}"))?;
            self.frames = Some(s);
        }
        let frames = self.frames.as_mut().expect("accepted above");
        let mut n = 0;
        while tokio::time::Instant::now() < deadline {
            let mut len = [0u8; 4];
            match tokio::time::timeout_at(deadline, frames.read_exact(&mut len)).await {
                Err(_) => break,
                Ok(Err(e)) => return Err(format!("the frame stream ended: {e}")),
                Ok(Ok(())) => {}
            }
            let len = u32::from_le_bytes(len);
            if !(32..=MAX_FRAME).contains(&len) {
                return Err(format!("a frame record of {len} bytes"));
            }
            let mut frame = vec![0u8; len as usize];
            frames
                .read_exact(&mut frame)
                .await
                .map_err(|e| format!("a frame record cut short: {e}"))?;
            let h = FrameHeader::parse(&frame).map_err(|e| format!("a frame's header: {e}"))?;
            self.seen.push((h.sequence, h.keyframe));
            if let Err(e) = self.decoder.receive(&frame) {
                return Err(format!("frame {} did not decode: {e}", h.sequence));
            }
            if let Some(d) = &mut self.digests {
                if d.len() == 256 {
                    d.pop_front();
                }
                let m = self.decoder.mirror();
                if let Some(s) = m.sequence() {
                    d.push_back((s, m.digest()));
                }
            }
            n += 1;
        }
        Ok(n)
    }

    /// Reads frames until one is a keyframe after the first `after` frames
    /// seen, for at most `wait`; whether one came.
    pub async fn await_keyframe(&mut self, after: usize, wait: Duration) -> Result<bool, String> {
        let deadline = tokio::time::Instant::now() + wait;
        while tokio::time::Instant::now() < deadline {
            if self.seen.iter().skip(after).any(|f| f.1) {
                return Ok(true);
            }
            self.read_frames(Duration::from_millis(100)).await?;
        }
        Ok(self.seen.iter().skip(after).any(|f| f.1))
    }

    /// How the connection ended, waiting at most `wait` for it to.
    pub async fn ended(&self, wait: Duration) -> Ended {
        match tokio::time::timeout(wait, self.conn.closed()).await {
            Ok(quinn::ConnectionError::ApplicationClosed(c)) => Ended::Closed(
                CloseCode::from_code(c.error_code.into_inner()),
                String::from_utf8_lossy(&c.reason).into_owned(),
            ),
            Ok(other) => Ended::Other(format!("ended without an application close: {other}")),
            Err(_) => Ended::Other(format!("still open after {} ms", wait.as_millis())),
        }
    }

    /// Waits for the connection to close with `code`; what happened
    /// instead otherwise.
    pub async fn expect_close(&self, code: CloseCode, wait: Duration) -> Result<(), String> {
        match self.ended(wait).await {
            Ended::Closed(c, _) if c == code => Ok(()),
            other => Err(format!("expected {}, got: {other}", code.name())),
        }
    }

    /// Closes the connection with `no_error`.
    pub fn close(&self) {
        self.conn.close(0u32.into(), b"conformance case done");
    }
}

/// The HELLO of spec/session.md section 8 (all compressions, point format
/// 0, 1 MiB limits, a 1 GiB mirror, a viewer).
pub fn example_hello() -> Hello {
    Hello {
        version: 1,
        compressions: 0b111,
        point_formats: 1,
        max_frame_bytes: 1 << 20,
        max_payload_bytes: 1 << 20,
        max_mirror_bytes: 1 << 30,
        viewer: true,
        overflow: false,
        digest: false,
    }
}

/// A HELLO that accepts everything this version defines, with 64 MiB
/// limits: for cases about what follows the handshake.
pub fn open_hello() -> Hello {
    Hello {
        point_formats: 0b11,
        max_frame_bytes: MAX_FRAME,
        max_payload_bytes: MAX_FRAME,
        max_mirror_bytes: 1 << 32,
        overflow: true,
        ..example_hello()
    }
}
