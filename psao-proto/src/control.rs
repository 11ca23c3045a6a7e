//! Control messages (spec/session.md, section 3): their byte layouts, and an
//! incremental reader that never buffers more than one message.

use bytes::{Buf, BufMut, BytesMut};
use glam::{Affine3A, Vec3};

use crate::codes::SessionError;

/// Largest `length` of a control message.
pub const MAX_CONTROL_LEN: usize = 1024;

/// Magic of `HELLO`.
pub const HELLO_MAGIC: [u8; 4] = *b"PSAO";

/// The protocol version.
pub const VERSION: u16 = 1;

/// Longest scene name or notice text, bytes.
pub const MAX_TEXT: usize = 200;

/// Message type ids.
pub mod kind {
    /// `HELLO`.
    pub const HELLO: u8 = 0x01;
    /// `WELCOME`.
    pub const WELCOME: u8 = 0x02;
    /// `CAMERA`.
    pub const CAMERA: u8 = 0x10;
    /// `ACK`.
    pub const ACK: u8 = 0x11;
    /// `KEYFRAME_REQUEST`.
    pub const KEYFRAME_REQUEST: u8 = 0x12;
    /// `MOVE_INSTANCE`.
    pub const MOVE_INSTANCE: u8 = 0x13;
    /// `DIGEST_REQUEST`.
    pub const DIGEST_REQUEST: u8 = 0x14;
    /// `NOTICE`.
    pub const NOTICE: u8 = 0x20;
    /// `DIGEST`.
    pub const DIGEST: u8 = 0x21;
}

/// `HELLO`: what the client decodes and accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hello {
    /// Protocol version (1).
    pub version: u16,
    /// Bit `i`: the client decodes compression id `i`.
    pub compressions: u8,
    /// Bit `i`: the client knows point format `i` (bits 0 and 1 are
    /// defined: spec/session.md 3.1).
    pub point_formats: u8,
    /// Largest frame it accepts.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload it accepts.
    pub max_payload_bytes: u32,
    /// Largest mirror it holds.
    pub max_mirror_bytes: u64,
    /// Whether it will send `CAMERA`.
    pub viewer: bool,
    /// Whether it decodes and reconstructs instances with overflow chains
    /// (`flags` bit 1; spec/wire-format.md 7.4).
    pub overflow: bool,
    /// Whether it checks mirror digests (`flags` bit 2; spec/session.md
    /// 3.8).
    pub digest: bool,
}

/// `WELCOME`: what the server will send.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Welcome {
    /// Protocol version (1).
    pub version: u16,
    /// The compression id every frame uses.
    pub compression: u8,
    /// The largest point format the frames use: 0, or 1 where some
    /// instances are in bind space (spec/wire-format.md 6.1).
    pub point_format: u8,
    /// Largest frame record of this session.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload of this session.
    pub max_payload_bytes: u32,
    /// Nominal frames per second.
    pub frame_rate: u16,
    /// Whether the server culls to this client's camera.
    pub culling: bool,
    /// Whether the frames may define instances with overflow chains
    /// (`flags` bit 1; spec/wire-format.md 7.4).
    pub overflow: bool,
    /// Whether the server sends this client `DIGEST` and takes
    /// `DIGEST_REQUEST` (`flags` bit 2; spec/session.md 3.8, 3.9).
    pub digest: bool,
    /// The scene's name (at most [`MAX_TEXT`] bytes).
    pub scene: String,
}

/// `CAMERA`: the client's view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPose {
    /// The client's clock, ms.
    pub time_ms: u32,
    /// Eye, world space.
    pub eye: Vec3,
    /// Target, world space.
    pub target: Vec3,
    /// Vertical field of view, radians, in (0, pi).
    pub fov_y: f32,
    /// Width / height, in [0.001, 1000].
    pub aspect: f32,
}

/// Why a keyframe is requested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyframeReason {
    /// A delta's base is not the mirror's state (0).
    Gap,
    /// A frame failed to decode (1).
    DecodeError,
    /// Anything else (2).
    Other,
    /// The client holds no state yet (3); `sequence` is 0.
    NoState,
    /// The mirror's digest differs from the server's `DIGEST` (4; only in
    /// a session with `digest`).
    DigestMismatch,
}

/// Notice codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoticeCode {
    /// 1: a scene event was refused.
    EventRefused,
    /// 2: a keyframe follows because the client fell behind.
    FellBehind,
    /// 4: the server runs below the frame rate its `WELCOME` announced
    /// (spec/session.md section 6; the text gives the measured rate).
    BelowRate,
    /// 3 (or any unknown code): something else.
    Other(u8),
}

/// A control message.
#[derive(Clone, Debug, PartialEq)]
pub enum Control {
    /// Client to server, first.
    Hello(Hello),
    /// Server to client, first.
    Welcome(Welcome),
    /// Client to server: its view.
    Camera(CameraPose),
    /// Client to server: the sequence its mirror reached.
    Ack(u32),
    /// Client to server: a keyframe, please.
    KeyframeRequest {
        /// The sequence held (0 with reason `NoState` when there is none).
        sequence: u32,
        /// Why.
        reason: KeyframeReason,
    },
    /// Client to server: place an instance.
    MoveInstance {
        /// The instance.
        instance: u32,
        /// Local to world.
        transform: Affine3A,
    },
    /// Server to client: for people.
    Notice {
        /// What about.
        code: NoticeCode,
        /// Text (at most [`MAX_TEXT`] bytes).
        text: String,
    },
    /// Server to client, in a session with `digest`: the mirror digest
    /// (spec/wire-format.md 7.5) after frame `sequence`.
    Digest {
        /// The frame's sequence.
        sequence: u32,
        /// The digest of the mirror after it.
        digest: u32,
    },
    /// Client to server, in a session with `digest`: a digest now, and one
    /// every `every` frames from now on (0: none periodic).
    DigestRequest {
        /// Frames between digests; 0 for none.
        every: u16,
    },
}

/// Truncates `s` to at most [`MAX_TEXT`] bytes on a character boundary.
pub fn clip_text(s: &str) -> &str {
    let mut end = s.len().min(MAX_TEXT);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

impl Control {
    /// The type id.
    pub fn kind(&self) -> u8 {
        match self {
            Control::Hello(_) => kind::HELLO,
            Control::Welcome(_) => kind::WELCOME,
            Control::Camera(_) => kind::CAMERA,
            Control::Ack(_) => kind::ACK,
            Control::KeyframeRequest { .. } => kind::KEYFRAME_REQUEST,
            Control::MoveInstance { .. } => kind::MOVE_INSTANCE,
            Control::Notice { .. } => kind::NOTICE,
            Control::Digest { .. } => kind::DIGEST,
            Control::DigestRequest { .. } => kind::DIGEST_REQUEST,
        }
    }

    /// Appends the message (length, type, body) to `out`. Texts longer
    /// than [`MAX_TEXT`] bytes are cut.
    pub fn encode(&self, out: &mut BytesMut) {
        let mut body = BytesMut::with_capacity(64);
        match self {
            Control::Hello(h) => {
                body.put_slice(&HELLO_MAGIC);
                body.put_u16_le(h.version);
                body.put_u8(h.compressions);
                body.put_u8(h.point_formats);
                body.put_u32_le(h.max_frame_bytes);
                body.put_u32_le(h.max_payload_bytes);
                body.put_u64_le(h.max_mirror_bytes);
                body.put_u8(h.viewer as u8 | (h.overflow as u8) << 1 | (h.digest as u8) << 2);
            }
            Control::Welcome(w) => {
                body.put_u16_le(w.version);
                body.put_u8(w.compression);
                body.put_u8(w.point_format);
                body.put_u32_le(w.max_frame_bytes);
                body.put_u32_le(w.max_payload_bytes);
                body.put_u16_le(w.frame_rate);
                body.put_u8(w.culling as u8 | (w.overflow as u8) << 1 | (w.digest as u8) << 2);
                let name = clip_text(&w.scene);
                body.put_u8(name.len() as u8);
                body.put_slice(name.as_bytes());
            }
            Control::Camera(c) => {
                body.put_u32_le(c.time_ms);
                for v in [c.eye, c.target] {
                    for x in v.to_array() {
                        body.put_f32_le(x);
                    }
                }
                body.put_f32_le(c.fov_y);
                body.put_f32_le(c.aspect);
            }
            Control::Ack(s) => body.put_u32_le(*s),
            Control::KeyframeRequest { sequence, reason } => {
                body.put_u32_le(*sequence);
                body.put_u8(match reason {
                    KeyframeReason::Gap => 0,
                    KeyframeReason::DecodeError => 1,
                    KeyframeReason::Other => 2,
                    KeyframeReason::NoState => 3,
                    KeyframeReason::DigestMismatch => 4,
                });
            }
            Control::MoveInstance {
                instance,
                transform,
            } => {
                body.put_u32_le(*instance);
                for x in transform.to_cols_array() {
                    body.put_f32_le(x);
                }
            }
            Control::Notice { code, text } => {
                body.put_u8(match code {
                    NoticeCode::EventRefused => 1,
                    NoticeCode::FellBehind => 2,
                    NoticeCode::BelowRate => 4,
                    NoticeCode::Other(c) => *c,
                });
                let text = clip_text(text);
                body.put_u8(text.len() as u8);
                body.put_slice(text.as_bytes());
            }
            Control::Digest { sequence, digest } => {
                body.put_u32_le(*sequence);
                body.put_u32_le(*digest);
            }
            Control::DigestRequest { every } => body.put_u16_le(*every),
        }
        out.put_u16_le(body.len() as u16 + 1);
        out.put_u8(self.kind());
        out.put_slice(&body);
    }

    /// The encoded message.
    pub fn to_bytes(&self) -> BytesMut {
        let mut b = BytesMut::new();
        self.encode(&mut b);
        b
    }

    /// Parses the body of a message of type `kind`.
    pub fn decode(kind: u8, mut b: &[u8]) -> Result<Control, SessionError> {
        let want = |n: usize, b: &[u8], name: &'static str| {
            if b.len() == n {
                Ok(())
            } else {
                Err(SessionError::malformed(
                    name,
                    format!("body is {} bytes, not {n}", b.len()),
                ))
            }
        };
        match kind {
            kind::HELLO => {
                // Magic and version first: a later version's HELLO may
                // have another size.
                if b.len() < 6 || b[..4] != HELLO_MAGIC {
                    return Err(SessionError::malformed("HELLO", "magic is not PSAO"));
                }
                let version = u16::from_le_bytes([b[4], b[5]]);
                if version != VERSION {
                    return Err(SessionError::VersionMismatch {
                        message: "HELLO",
                        version,
                        supported: VERSION,
                    });
                }
                want(25, b, "HELLO")?;
                b.advance(4);
                let h = Hello {
                    version: b.get_u16_le(),
                    compressions: b.get_u8(),
                    point_formats: b.get_u8(),
                    max_frame_bytes: b.get_u32_le(),
                    max_payload_bytes: b.get_u32_le(),
                    max_mirror_bytes: b.get_u64_le(),
                    viewer: false,
                    overflow: false,
                    digest: false,
                };
                let flags = b.get_u8();
                if h.version != VERSION {
                    return Err(SessionError::VersionMismatch {
                        message: "HELLO",
                        version: h.version,
                        supported: VERSION,
                    });
                }
                if h.compressions & 0xF8 != 0 || h.point_formats & 0xFC != 0 || flags & 0xF8 != 0 {
                    return Err(SessionError::malformed("HELLO", "a reserved bit is set"));
                }
                if h.compressions & 1 == 0 || h.point_formats & 1 == 0 {
                    return Err(SessionError::malformed(
                        "HELLO",
                        "must accept compression 0 and point format 0",
                    ));
                }
                if h.max_frame_bytes < 65_536 || h.max_payload_bytes < 65_536 {
                    return Err(SessionError::malformed(
                        "HELLO",
                        "limits below 65,536 bytes",
                    ));
                }
                Ok(Control::Hello(Hello {
                    viewer: flags & 1 == 1,
                    overflow: flags & 2 == 2,
                    digest: flags & 4 == 4,
                    ..h
                }))
            }
            kind::WELCOME => {
                // The version first: a later version's WELCOME may have
                // another layout.
                if b.len() >= 2 && u16::from_le_bytes([b[0], b[1]]) != VERSION {
                    return Err(SessionError::VersionMismatch {
                        message: "WELCOME",
                        version: u16::from_le_bytes([b[0], b[1]]),
                        supported: VERSION,
                    });
                }
                if b.len() < 16 {
                    return Err(SessionError::malformed(
                        "WELCOME",
                        "body shorter than 16 bytes",
                    ));
                }
                let version = b.get_u16_le();
                let compression = b.get_u8();
                let point_format = b.get_u8();
                let max_frame_bytes = b.get_u32_le();
                let max_payload_bytes = b.get_u32_le();
                let frame_rate = b.get_u16_le();
                let flags = b.get_u8();
                let n = b.get_u8() as usize;
                if b.len() != n || n > MAX_TEXT {
                    return Err(SessionError::malformed(
                        "WELCOME",
                        "scene name length does not add up",
                    ));
                }
                let scene = std::str::from_utf8(b)
                    .map_err(|_| SessionError::malformed("WELCOME", "scene name is not UTF-8"))?
                    .to_string();
                if version != VERSION {
                    return Err(SessionError::VersionMismatch {
                        message: "WELCOME",
                        version,
                        supported: VERSION,
                    });
                }
                if flags & 0xF8 != 0 {
                    return Err(SessionError::malformed("WELCOME", "a reserved bit is set"));
                }
                if !(1..=1000).contains(&frame_rate) || compression > 2 || point_format > 1 {
                    return Err(SessionError::malformed(
                        "WELCOME",
                        "a field is out of range",
                    ));
                }
                Ok(Control::Welcome(Welcome {
                    version,
                    compression,
                    point_format,
                    max_frame_bytes,
                    max_payload_bytes,
                    frame_rate,
                    culling: flags & 1 == 1,
                    overflow: flags & 2 == 2,
                    digest: flags & 4 == 4,
                    scene,
                }))
            }
            kind::CAMERA => {
                want(36, b, "CAMERA")?;
                let time_ms = b.get_u32_le();
                let f: [f32; 8] = finite_f32s(&mut b, "CAMERA")?;
                let c = CameraPose {
                    time_ms,
                    eye: Vec3::new(f[0], f[1], f[2]),
                    target: Vec3::new(f[3], f[4], f[5]),
                    fov_y: f[6],
                    aspect: f[7],
                };
                if c.eye == c.target
                    || !(c.fov_y > 0.0 && c.fov_y < std::f32::consts::PI)
                    || !(0.001..=1000.0).contains(&c.aspect)
                {
                    return Err(SessionError::malformed("CAMERA", "a field is out of range"));
                }
                Ok(Control::Camera(c))
            }
            kind::ACK => {
                want(4, b, "ACK")?;
                Ok(Control::Ack(b.get_u32_le()))
            }
            kind::KEYFRAME_REQUEST => {
                want(5, b, "KEYFRAME_REQUEST")?;
                let sequence = b.get_u32_le();
                let reason = match b.get_u8() {
                    0 => KeyframeReason::Gap,
                    1 => KeyframeReason::DecodeError,
                    2 => KeyframeReason::Other,
                    3 => KeyframeReason::NoState,
                    4 => KeyframeReason::DigestMismatch,
                    r => {
                        return Err(SessionError::malformed(
                            "KEYFRAME_REQUEST",
                            format!("reason {r}"),
                        ));
                    }
                };
                Ok(Control::KeyframeRequest { sequence, reason })
            }
            kind::MOVE_INSTANCE => {
                want(52, b, "MOVE_INSTANCE")?;
                let instance = b.get_u32_le();
                let m: [f32; 12] = finite_f32s(&mut b, "MOVE_INSTANCE")?;
                Ok(Control::MoveInstance {
                    instance,
                    transform: Affine3A::from_cols_array(&m),
                })
            }
            kind::NOTICE => {
                if b.len() < 2 {
                    return Err(SessionError::malformed(
                        "NOTICE",
                        "body shorter than 2 bytes",
                    ));
                }
                let code = match b.get_u8() {
                    1 => NoticeCode::EventRefused,
                    2 => NoticeCode::FellBehind,
                    4 => NoticeCode::BelowRate,
                    c => NoticeCode::Other(c),
                };
                let n = b.get_u8() as usize;
                if b.len() != n || n > MAX_TEXT {
                    return Err(SessionError::malformed(
                        "NOTICE",
                        "text length does not add up",
                    ));
                }
                let text = std::str::from_utf8(b)
                    .map_err(|_| SessionError::malformed("NOTICE", "text is not UTF-8"))?
                    .to_string();
                Ok(Control::Notice { code, text })
            }
            kind::DIGEST => {
                want(8, b, "DIGEST")?;
                Ok(Control::Digest {
                    sequence: b.get_u32_le(),
                    digest: b.get_u32_le(),
                })
            }
            kind::DIGEST_REQUEST => {
                want(2, b, "DIGEST_REQUEST")?;
                Ok(Control::DigestRequest {
                    every: b.get_u16_le(),
                })
            }
            k => Err(SessionError::UnknownMessage { kind: k }),
        }
    }
}

/// Reads `N` little-endian f32s off `b` (which holds at least `4 N`
/// bytes); a non-finite one is a violation in message `name`.
fn finite_f32s<const N: usize>(
    b: &mut &[u8],
    name: &'static str,
) -> Result<[f32; N], SessionError> {
    let mut out = [0f32; N];
    for x in &mut out {
        *x = b.get_f32_le();
    }
    if out.iter().all(|x| x.is_finite()) {
        Ok(out)
    } else {
        Err(SessionError::malformed(name, "holds a non-finite number"))
    }
}

/// Which side's messages a [`ControlReader`] takes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Sender {
    /// Any message (tools, tests).
    #[default]
    Either,
    /// The client's (`HELLO`, `CAMERA`, `ACK`, `KEYFRAME_REQUEST`,
    /// `MOVE_INSTANCE`): a server's reader.
    Client,
    /// The server's (`WELCOME`, `NOTICE`, `DIGEST`): a client's reader.
    Server,
}

impl Sender {
    /// Whether `kind` is a message type of the other role.
    fn refuses(self, kind: u8) -> bool {
        let from_server = matches!(kind, kind::WELCOME | kind::NOTICE | kind::DIGEST);
        let from_client = matches!(
            kind,
            kind::HELLO
                | kind::CAMERA
                | kind::ACK
                | kind::KEYFRAME_REQUEST
                | kind::MOVE_INSTANCE
                | kind::DIGEST_REQUEST
        );
        match self {
            Sender::Either => false,
            Sender::Client => from_server,
            Sender::Server => from_client,
        }
    }
}

/// Reads control messages out of a byte stream as it arrives, holding at
/// most one message (1,026 bytes) at a time.
#[derive(Debug, Default)]
pub struct ControlReader {
    buf: BytesMut,
    failed: bool,
    from: Sender,
}

impl ControlReader {
    /// A reader with nothing buffered, taking any message.
    pub fn new() -> ControlReader {
        ControlReader::default()
    }

    /// A reader of one side's messages: a message type of the other role
    /// is `protocol_violation` before its body is parsed (so a `WELCOME`
    /// sent to a server is a violation of role, not a version mismatch,
    /// spec/session.md 5.1).
    pub fn from(from: Sender) -> ControlReader {
        ControlReader {
            from,
            ..ControlReader::default()
        }
    }

    /// Takes bytes off `input` (as many as fit the message being read) and
    /// returns the next complete message, if any. Call again while it
    /// returns messages and `input` is not empty. After an error the
    /// reader stays failed.
    pub fn read(&mut self, input: &mut &[u8]) -> Result<Option<Control>, SessionError> {
        if self.failed {
            return Err(SessionError::StreamMisused(
                "control stream read after it failed",
            ));
        }
        let r = self.read_inner(input);
        if r.is_err() {
            self.failed = true;
        }
        r
    }

    fn read_inner(&mut self, input: &mut &[u8]) -> Result<Option<Control>, SessionError> {
        if self.buf.len() < 2 {
            let take = (2 - self.buf.len()).min(input.len());
            self.buf.extend_from_slice(&input[..take]);
            input.advance(take);
            if self.buf.len() < 2 {
                return Ok(None);
            }
        }
        let length = u16::from_le_bytes([self.buf[0], self.buf[1]]) as usize;
        if length == 0 || length > MAX_CONTROL_LEN {
            return Err(SessionError::MessageTooLarge { length });
        }
        let need = 2 + length - self.buf.len();
        let take = need.min(input.len());
        self.buf.extend_from_slice(&input[..take]);
        input.advance(take);
        if self.buf.len() < 2 + length {
            return Ok(None);
        }
        let msg = self.buf.split_to(2 + length);
        if self.from.refuses(msg[2]) {
            return Err(SessionError::Unexpected {
                kind: msg[2],
                rule: "is a message of the other role",
            });
        }
        Control::decode(msg[2], &msg[3..]).map(Some)
    }

    /// Bytes of a message read so far (for tests of the bound).
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }
}
