//! Application error codes for closing a connection (spec/session.md,
//! section 7), the typed errors that end a session, and how a connection
//! was closed.

use std::borrow::Cow;

/// Why a connection was closed: the QUIC application error code.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CloseCode {
    /// 0x00: the session ended normally.
    NoError,
    /// 0x01: a malformed or unexpected message or stream.
    ProtocolViolation,
    /// 0x02: `HELLO.version` is not 1.
    VersionMismatch,
    /// 0x03: no compression, point format or size both sides accept.
    CapabilityMismatch,
    /// 0x04: a control message `length` of 0 or above 1024.
    MessageTooLarge,
    /// 0x05: the client sent messages faster than allowed.
    RateExceeded,
    /// 0x06: no `HELLO` within 5 s.
    HandshakeTimeout,
    /// 0x07: the server is stopping.
    ServerShutdown,
    /// 0x08: the server serves as many clients as it is configured to.
    ServerFull,
    /// 0x09: the server failed; the client may reconnect.
    InternalError,
}

impl CloseCode {
    /// Every code, in order.
    pub const ALL: [CloseCode; 10] = [
        CloseCode::NoError,
        CloseCode::ProtocolViolation,
        CloseCode::VersionMismatch,
        CloseCode::CapabilityMismatch,
        CloseCode::MessageTooLarge,
        CloseCode::RateExceeded,
        CloseCode::HandshakeTimeout,
        CloseCode::ServerShutdown,
        CloseCode::ServerFull,
        CloseCode::InternalError,
    ];

    /// The code on the wire.
    pub fn code(self) -> u32 {
        match self {
            CloseCode::NoError => 0x00,
            CloseCode::ProtocolViolation => 0x01,
            CloseCode::VersionMismatch => 0x02,
            CloseCode::CapabilityMismatch => 0x03,
            CloseCode::MessageTooLarge => 0x04,
            CloseCode::RateExceeded => 0x05,
            CloseCode::HandshakeTimeout => 0x06,
            CloseCode::ServerShutdown => 0x07,
            CloseCode::ServerFull => 0x08,
            CloseCode::InternalError => 0x09,
        }
    }

    /// The code for a wire value; unknown values read as
    /// [`InternalError`](CloseCode::InternalError), as the spec says.
    pub fn from_code(code: u64) -> CloseCode {
        CloseCode::ALL
            .into_iter()
            .find(|c| c.code() as u64 == code)
            .unwrap_or(CloseCode::InternalError)
    }

    /// The name used in spec/session.md.
    pub fn name(self) -> &'static str {
        match self {
            CloseCode::NoError => "no_error",
            CloseCode::ProtocolViolation => "protocol_violation",
            CloseCode::VersionMismatch => "version_mismatch",
            CloseCode::CapabilityMismatch => "capability_mismatch",
            CloseCode::MessageTooLarge => "message_too_large",
            CloseCode::RateExceeded => "rate_exceeded",
            CloseCode::HandshakeTimeout => "handshake_timeout",
            CloseCode::ServerShutdown => "server_shutdown",
            CloseCode::ServerFull => "server_full",
            CloseCode::InternalError => "internal_error",
        }
    }
}

impl std::fmt::Display for CloseCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} (0x{:02x})", self.name(), self.code())
    }
}

/// Why a session must end, typed: what each side found wrong (or the end
/// it saw), each mapped to its close code by
/// [`close_code`](SessionError::close_code) (spec/session.md 7). The
/// sans-IO cores return it; the I/O layer closes the connection with
/// [`Close::from`] of it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SessionError {
    /// A control message whose body breaks its layout or ranges
    /// (spec/session.md 4): which message, and what.
    #[error("malformed {message}: {problem}")]
    Malformed {
        /// The message's name (`HELLO`, `WELCOME`, ...).
        message: &'static str,
        /// What is wrong with it.
        problem: Cow<'static, str>,
    },
    /// A control message of a type this side does not know.
    #[error("unknown control message type 0x{kind:02x}")]
    UnknownMessage {
        /// Its type byte.
        kind: u8,
    },
    /// A known control message where the session does not allow it.
    #[error("control message 0x{kind:02x} {rule}")]
    Unexpected {
        /// Its type byte.
        kind: u8,
        /// The rule it breaks ("before HELLO", "is not for a server here").
        rule: &'static str,
    },
    /// A stream used against spec/session.md 3: finished or reset early,
    /// or read after it failed.
    #[error("{0}")]
    StreamMisused(&'static str),
    /// A frame record whose length is out of range.
    #[error("frame record of {length} bytes (allowed {min}..={max})")]
    FrameRecordSize {
        /// The record's length field.
        length: u32,
        /// Smallest allowed.
        min: u32,
        /// Largest allowed (the negotiated `max_frame_bytes`).
        max: u32,
    },
    /// `HELLO` or `WELCOME` of another protocol version.
    #[error("{message} version {version} (this side speaks {supported})")]
    VersionMismatch {
        /// `HELLO` or `WELCOME`.
        message: &'static str,
        /// The version it carried.
        version: u16,
        /// The version spoken here.
        supported: u16,
    },
    /// No compression, point format or size both sides accept: what.
    #[error("{0}")]
    CapabilityMismatch(String),
    /// The client failed to decode this many keyframes in a row
    /// ([`MAX_FAILED_KEYFRAMES`](crate::MAX_FAILED_KEYFRAMES)): it cannot
    /// follow this stream.
    #[error("{failed} keyframes in a row failed to decode")]
    KeyframesFailed {
        /// How many.
        failed: u32,
    },
    /// A control message `length` of 0 or above 1024.
    #[error("control message length {length} (allowed 1..=1024)")]
    MessageTooLarge {
        /// The length field.
        length: usize,
    },
    /// The client sent control messages faster than allowed.
    #[error("more than {per_second} messages a second")]
    RateExceeded {
        /// The allowed rate.
        per_second: u32,
    },
    /// The handshake did not finish in time.
    #[error("no {awaited} within 5 s")]
    HandshakeTimeout {
        /// What did not come (`HELLO`, the control stream).
        awaited: &'static str,
    },
    /// The server serves as many clients as it is configured to (or
    /// refused the connection).
    #[error("server full")]
    ServerFull,
    /// The server finished its frame stream (it was shutting down) and
    /// its close did not arrive: how the connection ended instead.
    #[error("the server finished its frames, {how}")]
    ServerGone {
        /// What happened after the frame stream finished.
        how: String,
    },
    /// The transport failed (a QUIC or stream error, an idle timeout).
    #[error("{0}")]
    Transport(String),
    /// The session ended without anything wrong (closed here, the handle
    /// dropped, the peer went away before anything was said).
    #[error("{0}")]
    Ended(Cow<'static, str>),
}

impl SessionError {
    /// The close code this error ends the connection with.
    pub fn close_code(&self) -> CloseCode {
        match self {
            SessionError::Malformed { .. }
            | SessionError::UnknownMessage { .. }
            | SessionError::Unexpected { .. }
            | SessionError::StreamMisused(_)
            | SessionError::FrameRecordSize { .. } => CloseCode::ProtocolViolation,
            SessionError::VersionMismatch { .. } => CloseCode::VersionMismatch,
            SessionError::CapabilityMismatch(_) | SessionError::KeyframesFailed { .. } => {
                CloseCode::CapabilityMismatch
            }
            SessionError::MessageTooLarge { .. } => CloseCode::MessageTooLarge,
            SessionError::RateExceeded { .. } => CloseCode::RateExceeded,
            SessionError::HandshakeTimeout { .. } => CloseCode::HandshakeTimeout,
            SessionError::ServerFull => CloseCode::ServerFull,
            SessionError::ServerGone { .. } => CloseCode::ServerShutdown,
            SessionError::Transport(_) => CloseCode::InternalError,
            SessionError::Ended(_) => CloseCode::NoError,
        }
    }

    /// A [`Malformed`](SessionError::Malformed) error.
    pub fn malformed(message: &'static str, problem: impl Into<Cow<'static, str>>) -> Self {
        SessionError::Malformed {
            message,
            problem: problem.into(),
        }
    }
}

/// How a connection was closed, as on the wire: the code and a short text
/// for people (from a [`SessionError`] here, or as the peer sent it).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{code}: {reason}")]
pub struct Close {
    /// The code.
    pub code: CloseCode,
    /// What went wrong.
    pub reason: String,
}

impl From<SessionError> for Close {
    fn from(e: SessionError) -> Close {
        Close::new(e.close_code(), e.to_string())
    }
}

impl Close {
    /// A close with `code` and `reason`.
    pub fn new(code: CloseCode, reason: impl Into<String>) -> Close {
        Close {
            code,
            reason: reason.into(),
        }
    }
}
