//! Application error codes for closing a connection (spec/session.md,
//! section 7).

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

/// A reason to close a connection: the code and a short text for people.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{code}: {reason}")]
pub struct Close {
    /// The code.
    pub code: CloseCode,
    /// What went wrong.
    pub reason: String,
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
