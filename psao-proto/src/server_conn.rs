//! The server side of one connection, sans-IO: control bytes and the time
//! in, events and bytes to send out. It negotiates (spec/session.md, 3.1,
//! 3.2), enforces the handshake timeout and the uplink rate, and turns
//! uplink messages into events for the server.

use std::time::{Duration, Instant};

use bytes::Bytes;
use glam::Affine3A;

use crate::codes::SessionError;
use crate::control::{
    CameraPose, Control, ControlReader, Hello, KeyframeReason, NoticeCode, VERSION, Welcome,
};

/// How long a client may take to send `HELLO`.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// Uplink messages a client may send in a burst (and per second).
pub const UPLINK_RATE: f64 = 256.0;

/// What the server offers every client.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Offer {
    /// The compression id of the stream (frames are encoded once).
    pub compression: u8,
    /// Largest frame it will ever send (its encoder's limit): `WELCOME`
    /// says the smaller of this and the client's `HELLO`.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload it will ever send.
    pub max_payload_bytes: u32,
    /// Largest frame it has sent so far, keyframes included: a client
    /// whose `HELLO` accepts less is refused, naming this size. Frames
    /// larger than a client's limit that come later are not sent to it
    /// (spec/session.md 3.2).
    pub largest_frame: u32,
    /// Largest uncompressed payload it has sent so far.
    pub largest_payload: u32,
    /// Bytes of the mirror a client needs for the scene.
    pub mirror_bytes: u64,
    /// The largest point format the frames use (`WELCOME.point_format`).
    pub point_format: u8,
    /// Whether the frames define instances with overflow chains
    /// (`WELCOME.flags.overflow`; spec/wire-format.md 7.4).
    pub overflow: bool,
    /// Nominal frames per second.
    pub frame_rate: u16,
    /// The scene's name.
    pub scene: String,
    /// Whether the server culls to its viewers' views (`WELCOME`'s
    /// `flags.culling` for a viewer; a non-viewer is told 0).
    pub culling: bool,
    /// Whether it sends mirror digests to clients that check them
    /// (`WELCOME.flags.digest` for a client whose `HELLO` set it).
    pub digest: bool,
}

/// Checks a client's `HELLO` against the offer; the `WELCOME` to send, or
/// why the connection must close.
pub fn negotiate(hello: &Hello, offer: &Offer) -> Result<Welcome, SessionError> {
    let mismatch = |why: String| Err(SessionError::CapabilityMismatch(why));
    if hello.compressions & (1 << offer.compression) == 0 {
        return mismatch(format!(
            "the stream uses compression {}, which the client does not decode",
            offer.compression
        ));
    }
    // Formats are cumulative: a session of format 1 defines instances of
    // formats 0 and 1.
    let formats = (2u16 << offer.point_format.min(7)) - 1;
    if u16::from(hello.point_formats) & formats != formats {
        return mismatch(format!(
            "the scene's frames use point formats 0 to {} (1: deforming meshes in bind space), the client knows {:#04x}",
            offer.point_format, hello.point_formats
        ));
    }
    if offer.overflow && !hello.overflow {
        return mismatch(
            "the scene's frames use overflow chains (spec/wire-format.md 7.4), which the client does not decode"
                .to_string(),
        );
    }
    if hello.max_frame_bytes < offer.largest_frame
        || hello.max_payload_bytes < offer.largest_payload
    {
        return mismatch(format!(
            "this session's frames reach {} bytes ({} uncompressed); the client accepts {} ({})",
            offer.largest_frame,
            offer.largest_payload,
            hello.max_frame_bytes,
            hello.max_payload_bytes
        ));
    }
    if hello.max_mirror_bytes < offer.mirror_bytes {
        return mismatch(format!(
            "the scene needs a {} byte mirror, the client holds {}",
            offer.mirror_bytes, hello.max_mirror_bytes
        ));
    }
    Ok(Welcome {
        version: VERSION,
        compression: offer.compression,
        point_format: offer.point_format,
        max_frame_bytes: offer.max_frame_bytes.min(hello.max_frame_bytes),
        max_payload_bytes: offer.max_payload_bytes.min(hello.max_payload_bytes),
        frame_rate: offer.frame_rate,
        // Culling is to a viewer's camera: a client that sends none is not
        // culled for (its presence turns culling off, spec/session.md 3.2).
        culling: offer.culling && hello.viewer,
        overflow: offer.overflow,
        digest: offer.digest && hello.digest,
        scene: offer.scene.clone(),
    })
}

/// A token bucket: `rate` tokens per second, at most `rate` banked.
#[derive(Clone, Copy, Debug)]
pub struct TokenBucket {
    rate: f64,
    tokens: f64,
    at: Instant,
}

impl TokenBucket {
    /// A full bucket.
    pub fn new(rate: f64, now: Instant) -> TokenBucket {
        TokenBucket {
            rate,
            tokens: rate,
            at: now,
        }
    }

    /// Takes one token; false when empty.
    pub fn take(&mut self, now: Instant) -> bool {
        let dt = now.saturating_duration_since(self.at).as_secs_f64();
        self.tokens = (self.tokens + dt * self.rate).min(self.rate);
        self.at = now;
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// What a client asked for.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ServerEvent {
    /// The handshake is done: send these bytes (`WELCOME`), then a
    /// keyframe on the frame stream.
    Welcomed {
        /// The encoded `WELCOME`.
        bytes: Bytes,
        /// Whether the client will send camera poses.
        viewer: bool,
    },
    /// The client's view.
    Camera(CameraPose),
    /// The client's mirror reached this sequence.
    Ack(u32),
    /// The client needs a keyframe.
    KeyframeRequested(KeyframeReason),
    /// The client asks for a digest now and every `every` frames (0: no
    /// periodic ones); only in a session with `digest`.
    DigestRequested {
        /// Frames between digests.
        every: u16,
    },
    /// The client asks to place an instance.
    Move {
        /// The instance.
        instance: u32,
        /// Local to world.
        transform: Affine3A,
    },
}

/// The state of one connection.
#[derive(Debug)]
pub struct ServerConn {
    offer: Offer,
    reader: ControlReader,
    bucket: TokenBucket,
    opened: Instant,
    hello: Option<Hello>,
}

impl ServerConn {
    /// A connection opened at `now`.
    pub fn new(offer: Offer, now: Instant) -> ServerConn {
        ServerConn {
            offer,
            reader: ControlReader::from(crate::control::Sender::Client),
            bucket: TokenBucket::new(UPLINK_RATE, now),
            opened: now,
            hello: None,
        }
    }

    /// The largest frame and payload the server has sent so far, for the
    /// `HELLO` still to come (see [`Offer::largest_frame`]).
    pub fn frames_so_far(&mut self, largest_frame: u32, largest_payload: u32) {
        self.offer.largest_frame = largest_frame;
        self.offer.largest_payload = largest_payload;
    }

    /// Whether this session has digests (both sides offered them).
    fn digests(&self, hello: &Hello) -> bool {
        self.offer.digest && hello.digest
    }

    /// The client's `HELLO`, once it came.
    pub fn hello(&self) -> Option<&Hello> {
        self.hello.as_ref()
    }

    /// When the handshake times out (`None` once `HELLO` came).
    pub fn deadline(&self) -> Option<Instant> {
        self.hello
            .is_none()
            .then(|| self.opened + HANDSHAKE_TIMEOUT)
    }

    /// Checks the handshake deadline.
    pub fn on_timer(&self, now: Instant) -> Result<(), SessionError> {
        match self.deadline() {
            Some(d) if now >= d => Err(SessionError::HandshakeTimeout { awaited: "HELLO" }),
            _ => Ok(()),
        }
    }

    /// Bytes from the control stream at `now`; appends what they ask for
    /// to `events`.
    pub fn on_control(
        &mut self,
        mut input: &[u8],
        now: Instant,
        events: &mut Vec<ServerEvent>,
    ) -> Result<(), SessionError> {
        self.on_timer(now)?;
        while !input.is_empty() {
            let Some(msg) = self.reader.read(&mut input)? else {
                break;
            };
            if !self.bucket.take(now) {
                return Err(SessionError::RateExceeded {
                    per_second: UPLINK_RATE as u32,
                });
            }
            let event = match (msg, &self.hello) {
                (Control::Hello(h), None) => {
                    let welcome = negotiate(&h, &self.offer)?;
                    self.hello = Some(h);
                    ServerEvent::Welcomed {
                        bytes: Control::Welcome(welcome).to_bytes().freeze(),
                        viewer: h.viewer,
                    }
                }
                (m, None) => {
                    return Err(SessionError::Unexpected {
                        kind: m.kind(),
                        rule: "before HELLO",
                    });
                }
                (Control::Camera(c), Some(h)) if h.viewer => ServerEvent::Camera(c),
                (Control::Ack(s), Some(_)) => ServerEvent::Ack(s),
                (Control::KeyframeRequest { reason, .. }, Some(h))
                    if reason != KeyframeReason::DigestMismatch || self.digests(h) =>
                {
                    ServerEvent::KeyframeRequested(reason)
                }
                (Control::DigestRequest { every }, Some(h)) if self.digests(h) => {
                    ServerEvent::DigestRequested { every }
                }
                (
                    Control::MoveInstance {
                        instance,
                        transform,
                    },
                    Some(_),
                ) => ServerEvent::Move {
                    instance,
                    transform,
                },
                (m, Some(_)) => {
                    return Err(SessionError::Unexpected {
                        kind: m.kind(),
                        rule: "is not for a server here",
                    });
                }
            };
            events.push(event);
        }
        Ok(())
    }
}

/// A `NOTICE` as bytes.
pub fn notice(code: NoticeCode, text: &str) -> Bytes {
    Control::Notice {
        code,
        text: text.to_string(),
    }
    .to_bytes()
    .freeze()
}
