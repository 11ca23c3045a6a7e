//! The client side of a session, sans-IO: bytes from the control and frame
//! streams in, events and control bytes to send out. It keeps a
//! [`Decoder`] (and its [`Mirror`]) in sync, asks for keyframes when it
//! must, and acknowledges frames.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use bytes::{Bytes, BytesMut};
use glam::Affine3A;
use psao_codec::wire::FrameHeader;
use psao_codec::wire::sequence::is_newer;
use psao_codec::{Compression, DecodeError, Decoder, Event, Limits, Mirror};

use crate::codes::SessionError;
use crate::control::{
    CameraPose, Control, ControlReader, Hello, KeyframeReason, NoticeCode, VERSION, Welcome,
};
use crate::records::RecordReader;

/// What a client accepts and does.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClientConfig {
    /// Decoder limits (frame, payload and mirror sizes are announced in
    /// `HELLO`).
    pub limits: Limits,
    /// Whether it will send camera poses.
    pub viewer: bool,
    /// Whether received frames are kept for [`ClientSession::take_captured`]
    /// (recording a session).
    pub capture: bool,
    /// Offer point format 0 only: for a renderer that cannot give its
    /// pixels bind-space attributes (spec/wire-format.md 6.1). A server
    /// whose frames use point format 1 then refuses the client with
    /// `capability_mismatch`. Default: formats 0 and 1.
    pub point_format_0_only: bool,
    /// Do not offer overflow chains (spec/wire-format.md 7.4): for a
    /// renderer whose lookup stops at a cell's own key. A server whose
    /// frames use chains then refuses the client with
    /// `capability_mismatch`. Default: offered (the decoder and
    /// [`psao_codec::reconstruct_ao`] follow chains).
    pub no_overflow: bool,
    /// Do not offer mirror digests (spec/session.md 3.8): for a server
    /// from before they were specified, which refuses the flag. Default:
    /// offered, and every `DIGEST` is checked.
    pub no_digest: bool,
}

/// What happened on a session.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum ClientEvent {
    /// The server answered `HELLO`.
    Welcomed(Welcome),
    /// A frame was applied; the mirror is at `sequence`.
    Applied {
        /// The mirror's sequence.
        sequence: u32,
        /// Whether it was a keyframe.
        keyframe: bool,
    },
    /// A frame older than the mirror was ignored.
    Stale {
        /// Its sequence.
        sequence: u32,
    },
    /// A delta did not follow the mirror's state: a keyframe was requested.
    Gap {
        /// The delta's base.
        base: u32,
    },
    /// A frame failed to decode (the mirror is unchanged): a keyframe was
    /// requested.
    DecodeFailed(DecodeError),
    /// A frame's header named a compression other than `WELCOME`'s or 0
    /// (spec/session.md 3.2): a decode failure, the frame was not applied
    /// and a keyframe was requested.
    WrongCompression {
        /// The frame's sequence.
        sequence: u32,
        /// The compression id its header named.
        compression: u8,
    },
    /// A `DIGEST` was checked against the mirror (spec/session.md 3.8);
    /// on a mismatch a keyframe was requested (reason 4).
    DigestChecked {
        /// The sequence it was for.
        sequence: u32,
        /// Whether the mirror's digest was the server's.
        matched: bool,
    },
    /// The server said something.
    Notice {
        /// About what.
        code: NoticeCode,
        /// For people.
        text: String,
    },
}

/// Counters of a client session.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClientStats {
    /// Frames applied.
    pub applied: u64,
    /// Keyframes among them.
    pub keyframes: u64,
    /// Frames that failed to decode.
    pub failed: u64,
    /// Stale frames ignored.
    pub stale: u64,
    /// Keyframes requested.
    pub requests: u64,
    /// Frame bytes received.
    pub bytes: u64,
    /// `DIGEST`s checked and found equal to the mirror's.
    pub digests_matched: u64,
    /// `DIGEST`s checked and found different (each asked for a keyframe).
    pub digest_mismatches: u64,
    /// `DIGEST`s dropped unchecked: the mirror had moved past their
    /// sequence, or jumped over it (spec/session.md 3.8).
    pub digests_dropped: u64,
}

/// One client session.
#[derive(Debug)]
pub struct ClientSession {
    config: ClientConfig,
    welcome: Option<Welcome>,
    control: ControlReader,
    records: RecordReader,
    decoder: Decoder,
    transmit: BytesMut,
    events: VecDeque<ClientEvent>,
    /// A keyframe was requested and has not arrived yet.
    requested: bool,
    /// Frames since that request (a lost request is repeated after about
    /// 2 s of frames).
    since_request: u32,
    /// When the outstanding request was first seen by
    /// [`ClientSession::handle_timeout`] (a lost request is also repeated after
    /// [`REQUEST_RETRY`] of time, for a scene so still that no frames come).
    request_seen: Option<Instant>,
    /// Keyframes in a row that failed to decode.
    failed_keyframes: u32,
    /// Why the outstanding request was made (a repeat says the same).
    request_reason: KeyframeReason,
    /// Frames applied since the last `ACK`.
    since_ack: u32,
    stats: ClientStats,
    captured: Vec<Bytes>,
    /// Events dropped because the queue was full.
    events_dropped: u64,
    /// A keyframe request made before `WELCOME`, sent when it comes.
    deferred: Option<Control>,
    /// The latest time [`ClientSession::handle_timeout`] was given.
    now: Option<Instant>,
    /// When the server finished the frame stream (it is shutting down).
    frames_finished: Option<Instant>,
    /// A `DIGEST` for a sequence the mirror has not reached yet.
    pending_digest: Option<(u32, u32)>,
    /// A keyframe applied before `WELCOME` (the streams race): its `ACK`
    /// goes out when `WELCOME` comes.
    deferred_ack: Option<u32>,
}

/// Most events a session queues; older ones are dropped when the caller
/// does not poll.
pub const MAX_EVENTS: usize = 1024;

/// How long a keyframe request may go unanswered before it is sent again
/// (spec/session.md 3.5: about 2 s).
pub const REQUEST_RETRY: Duration = Duration::from_secs(2);

/// How long a client waits for the server's close once the frame stream
/// has finished (spec/session.md 5.3): the server closes within about a
/// second of finishing it, so past this its close was lost.
pub const CLOSE_AFTER_FRAMES: Duration = Duration::from_secs(3);

/// Keyframes in a row that may fail to decode before the client closes
/// with `capability_mismatch` (spec/session.md 3.5).
pub const MAX_FAILED_KEYFRAMES: u32 = 2;

/// Bit mask of the compressions this build decodes.
pub fn decodable_compressions() -> u8 {
    [Compression::None, Compression::Lz4, Compression::Zstd]
        .into_iter()
        .filter(|c| c.decodable())
        .fold(0, |m, c| m | 1 << c.id())
}

/// The smallest frame and payload limits a `HELLO` may offer.
const MIN_OFFERED_BYTES: u32 = 65_536;

/// The point formats a client of `config` offers in `HELLO`: 0 and 1 (the
/// decoder applies both alike; the mirror reports each instance's,
/// spec/wire-format.md 6.1), or 0 alone.
fn point_formats_of(config: &ClientConfig) -> u8 {
    if config.point_format_0_only {
        0b01
    } else {
        0b11
    }
}

impl ClientSession {
    /// A session that has queued its `HELLO` (its limits raised to the
    /// 65,536 bytes `HELLO` must offer at least, for the decoder too).
    pub fn new(mut config: ClientConfig) -> ClientSession {
        // HELLO may not offer less than 65,536 bytes (spec/session.md
        // 3.1): the limits it offers are the ones the decoder keeps.
        config.limits.max_frame_bytes = config.limits.max_frame_bytes.max(MIN_OFFERED_BYTES);
        config.limits.max_payload_bytes = config.limits.max_payload_bytes.max(MIN_OFFERED_BYTES);
        let mut transmit = BytesMut::new();
        Control::Hello(Hello {
            version: VERSION,
            compressions: decodable_compressions(),
            point_formats: point_formats_of(&config),
            max_frame_bytes: config.limits.max_frame_bytes,
            max_payload_bytes: config.limits.max_payload_bytes,
            max_mirror_bytes: config.limits.max_mirror_bytes,
            viewer: config.viewer,
            overflow: !config.no_overflow,
            digest: !config.no_digest,
        })
        .encode(&mut transmit);
        ClientSession {
            records: RecordReader::new(config.limits.max_frame_bytes),
            decoder: Decoder::new(config.limits),
            config,
            welcome: None,
            control: ControlReader::from(crate::control::Sender::Server),
            transmit,
            events: VecDeque::new(),
            requested: false,
            since_request: 0,
            request_seen: None,
            failed_keyframes: 0,
            request_reason: KeyframeReason::Other,
            since_ack: u32::MAX,
            stats: ClientStats::default(),
            captured: Vec::new(),
            events_dropped: 0,
            deferred: None,
            now: None,
            frames_finished: None,
            pending_digest: None,
            deferred_ack: None,
        }
    }

    /// Whether a keyframe was asked for and has not come yet.
    pub fn awaiting_keyframe(&self) -> bool {
        self.requested
    }

    /// The server's `WELCOME`, once it came.
    pub fn welcome(&self) -> Option<&Welcome> {
        self.welcome.as_ref()
    }

    /// The mirror of the server's grids.
    pub fn mirror(&self) -> &Mirror {
        self.decoder.mirror()
    }

    /// The mirror, to take its change list after uploading.
    pub fn mirror_mut(&mut self) -> &mut Mirror {
        self.decoder.mirror_mut()
    }

    /// Counters.
    pub fn stats(&self) -> ClientStats {
        self.stats
    }

    /// The point formats its `HELLO` offered.
    fn point_formats(&self) -> u8 {
        point_formats_of(&self.config)
    }

    /// Bytes from the control stream.
    pub fn on_control(&mut self, mut input: &[u8]) -> Result<(), SessionError> {
        while !input.is_empty() {
            let Some(msg) = self.control.read(&mut input)? else {
                break;
            };
            match msg {
                Control::Welcome(w) if self.welcome.is_none() => {
                    let ours = decodable_compressions();
                    if ours & (1 << w.compression) == 0
                        || self.point_formats() & (1 << w.point_format.min(7)) == 0
                        || (w.overflow && self.config.no_overflow)
                        || (w.digest && self.config.no_digest)
                        || w.max_frame_bytes > self.config.limits.max_frame_bytes
                        || w.max_payload_bytes > self.config.limits.max_payload_bytes
                    {
                        return Err(SessionError::CapabilityMismatch(
                            "WELCOME chose what HELLO did not offer".into(),
                        ));
                    }
                    self.records.limit(w.max_frame_bytes);
                    self.welcome = Some(w.clone());
                    self.push_event(ClientEvent::Welcomed(w));
                    // Whatever frames arrived before WELCOME asked for is
                    // sent now (nothing but HELLO goes out before it).
                    if let Some(Control::KeyframeRequest { sequence, reason }) =
                        self.deferred.take()
                    {
                        Control::KeyframeRequest { sequence, reason }.encode(&mut self.transmit);
                    }
                    // And a keyframe applied before it is acknowledged now,
                    // if the mirror is still there.
                    if let Some(seq) = self.deferred_ack.take()
                        && self.decoder.mirror().sequence() == Some(seq)
                    {
                        Control::Ack(seq).encode(&mut self.transmit);
                    }
                }
                Control::Notice { code, text } if self.welcome.is_some() => {
                    self.push_event(ClientEvent::Notice { code, text });
                }
                Control::Digest { sequence, digest }
                    if self.welcome.as_ref().is_some_and(|w| w.digest) =>
                {
                    self.pending_digest = Some((sequence, digest));
                    self.check_digest();
                }
                other => {
                    return Err(SessionError::Unexpected {
                        kind: other.kind(),
                        rule: "is not for a client here",
                    });
                }
            }
        }
        Ok(())
    }

    /// Bytes from the frame stream.
    pub fn on_frames(&mut self, mut input: &[u8]) -> Result<(), SessionError> {
        while !input.is_empty() {
            let Some(frame) = self.records.read(&mut input)? else {
                break;
            };
            self.stats.bytes += frame.len() as u64 + 4;
            let applied = self.apply(&frame);
            if self.config.capture {
                self.captured.push(frame);
            }
            applied?;
        }
        Ok(())
    }

    /// Applies one frame (from a frame record or any other transport, a
    /// capture file for instance). A frame that fails to decode leaves the
    /// mirror as it was and asks for a keyframe; the session must close
    /// (the error says how) when [`MAX_FAILED_KEYFRAMES`] keyframes in a
    /// row failed, since asking again would not help.
    pub fn apply(&mut self, frame: &[u8]) -> Result<(), SessionError> {
        let header = FrameHeader::parse(frame).ok();
        let is_keyframe = header.is_some_and(|h| h.keyframe);
        if let (Some(h), Some(w)) = (header, &self.welcome) {
            let id = h.compression.id();
            if id != 0 && id != w.compression {
                self.stats.failed += 1;
                self.request(KeyframeReason::DecodeError);
                self.push_event(ClientEvent::WrongCompression {
                    sequence: h.sequence,
                    compression: id,
                });
                return self.keyframe_failed(is_keyframe);
            }
        }
        match self.decoder.receive(frame) {
            Ok(Event::Applied { sequence, keyframe }) => {
                self.stats.applied += 1;
                if keyframe {
                    self.stats.keyframes += 1;
                    self.requested = false;
                    self.request_seen = None;
                    self.failed_keyframes = 0;
                }
                // At most about 10 ACKs a second (spec/session.md, 3.4),
                // and always one for a keyframe.
                let every = self
                    .welcome
                    .as_ref()
                    .map_or(6, |w| (w.frame_rate as u32 / 10).max(1));
                self.since_ack = self.since_ack.saturating_add(1);
                if (keyframe || self.since_ack >= every) && self.welcome.is_some() {
                    self.since_ack = 0;
                    Control::Ack(sequence).encode(&mut self.transmit);
                } else if keyframe {
                    self.deferred_ack = Some(sequence);
                }
                self.push_event(ClientEvent::Applied { sequence, keyframe });
                self.check_digest();
            }
            Ok(Event::Stale { sequence, .. }) => {
                self.stats.stale += 1;
                self.push_event(ClientEvent::Stale { sequence });
            }
            Ok(Event::NeedKeyframe { base, .. }) => {
                self.request(KeyframeReason::Gap);
                self.push_event(ClientEvent::Gap { base });
            }
            // An outcome a later codec adds: nothing this session counts.
            Ok(_) => {}
            Err(e) => {
                self.stats.failed += 1;
                self.request(KeyframeReason::DecodeError);
                self.push_event(ClientEvent::DecodeFailed(e));
                return self.keyframe_failed(is_keyframe);
            }
        }
        Ok(())
    }

    /// Asks for a digest now and one every `every` frames (0: none
    /// periodic; spec/session.md 3.9). Nothing is sent in a session
    /// without `digest`; returns whether the request was queued.
    pub fn request_digests(&mut self, every: u16) -> bool {
        if !self.welcome.as_ref().is_some_and(|w| w.digest) {
            return false;
        }
        Control::DigestRequest { every }.encode(&mut self.transmit);
        true
    }

    /// Compares the pending `DIGEST` with the mirror when it is at its
    /// sequence; drops it once the mirror is past it (spec/session.md 3.8).
    fn check_digest(&mut self) {
        let Some((sequence, digest)) = self.pending_digest else {
            return;
        };
        let Some(at) = self.decoder.mirror().sequence() else {
            self.pending_digest = None;
            self.stats.digests_dropped += 1;
            return;
        };
        if at == sequence {
            self.pending_digest = None;
            let matched = self.decoder.mirror().digest() == Some(digest);
            if matched {
                self.stats.digests_matched += 1;
            } else {
                self.stats.digest_mismatches += 1;
                self.request(KeyframeReason::DigestMismatch);
            }
            self.push_event(ClientEvent::DigestChecked { sequence, matched });
        } else if !is_newer(sequence, at) {
            // The mirror moved past it (or jumped over it).
            self.pending_digest = None;
            self.stats.digests_dropped += 1;
        }
    }

    /// Counts a failed frame against the keyframes-in-a-row limit.
    fn keyframe_failed(&mut self, keyframe: bool) -> Result<(), SessionError> {
        if !keyframe {
            return Ok(());
        }
        self.failed_keyframes += 1;
        if self.failed_keyframes >= MAX_FAILED_KEYFRAMES {
            return Err(SessionError::KeyframesFailed {
                failed: self.failed_keyframes,
            });
        }
        Ok(())
    }

    /// The server finished the frame stream at `now`: it is shutting down
    /// and its close follows (spec/session.md 5.3). If the close has not
    /// come [`CLOSE_AFTER_FRAMES`] later, [`handle_timeout`] ends the
    /// session as `server_shutdown`.
    ///
    /// [`handle_timeout`]: ClientSession::handle_timeout
    pub fn on_frames_finished(&mut self, now: Instant) {
        self.frames_finished.get_or_insert(now);
    }

    /// Whether the server finished the frame stream.
    pub fn frames_finished(&self) -> bool {
        self.frames_finished.is_some()
    }

    /// How the session reads when the transport ended without a close
    /// from the server (a timeout, a reset; `why` says which): once the
    /// frame stream has finished the server was shutting down and its
    /// close was lost on the way, so `server_shutdown`; before that,
    /// `internal_error` (spec/session.md 5.3 and 7).
    pub fn transport_lost(&self, why: &str) -> SessionError {
        if self.frames_finished() {
            SessionError::ServerGone {
                how: format!("then the connection ended without its close: {why}"),
            }
        } else {
            SessionError::Transport(why.to_string())
        }
    }

    /// When [`handle_timeout`](ClientSession::handle_timeout) must next be
    /// called (`None`: nothing waits on time): to repeat an unanswered
    /// keyframe request, or to end the session when the server's close
    /// did not follow its finished frame stream.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let retry = if self.requested {
            // A request not yet seen by handle_timeout is stamped at the
            // next call: as soon as possible.
            self.request_seen.map(|t| t + REQUEST_RETRY).or(self.now)
        } else {
            None
        };
        let close = self.frames_finished.map(|t| t + CLOSE_AFTER_FRAMES);
        match (retry, close) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Lets time pass (call it at [`poll_timeout`] and after input): an
    /// outstanding keyframe request that went unanswered for
    /// [`REQUEST_RETRY`] is sent again, even when no frames arrive to
    /// count (a still scene sends none); [`CLOSE_AFTER_FRAMES`] after the
    /// frame stream finished, the session ends with `server_shutdown`
    /// (the error, for the I/O layer to close with).
    ///
    /// [`poll_timeout`]: ClientSession::poll_timeout
    pub fn handle_timeout(&mut self, now: Instant) -> Result<(), SessionError> {
        self.now = Some(self.now.map_or(now, |t| t.max(now)));
        if let Some(done) = self.frames_finished
            && now.saturating_duration_since(done) >= CLOSE_AFTER_FRAMES
        {
            return Err(SessionError::ServerGone {
                how: "and its close did not arrive".into(),
            });
        }
        self.retry_request(now);
        Ok(())
    }

    fn retry_request(&mut self, now: Instant) {
        if !self.requested {
            self.request_seen = None;
            return;
        }
        match self.request_seen {
            None => self.request_seen = Some(now),
            Some(seen) if now.saturating_duration_since(seen) >= REQUEST_RETRY => {
                self.requested = false;
                self.request(self.request_reason);
                self.request_seen = Some(now);
            }
            Some(_) => {}
        }
    }

    fn request(&mut self, reason: KeyframeReason) {
        if self.requested {
            // One request per keyframe awaited; repeated only if none came
            // within about 2 s of frames.
            self.since_request += 1;
            let patience = self
                .welcome
                .as_ref()
                .map_or(120, |w| 2 * w.frame_rate as u32);
            if self.since_request < patience {
                return;
            }
        }
        self.requested = true;
        self.since_request = 0;
        self.request_reason = reason;
        // The time-based repeat counts from this request.
        self.request_seen = None;
        self.stats.requests += 1;
        let (sequence, reason) = match self.decoder.mirror().sequence() {
            Some(s) => (s, reason),
            None => (0, KeyframeReason::NoState),
        };
        let msg = Control::KeyframeRequest { sequence, reason };
        if self.welcome.is_some() {
            msg.encode(&mut self.transmit);
        } else {
            self.deferred = Some(msg);
        }
    }

    fn push_event(&mut self, e: ClientEvent) {
        if self.events.len() >= MAX_EVENTS {
            self.events.pop_front();
            self.events_dropped += 1;
        }
        self.events.push_back(e);
    }

    /// Events dropped because more than [`MAX_EVENTS`] waited unpolled.
    pub fn events_dropped(&self) -> u64 {
        self.events_dropped
    }

    /// Queues a camera pose (only a viewer may; others ignore the call and
    /// return false).
    pub fn send_camera(&mut self, pose: CameraPose) -> bool {
        if !self.config.viewer {
            return false;
        }
        Control::Camera(pose).encode(&mut self.transmit);
        true
    }

    /// Queues a request to place an instance.
    pub fn send_move(&mut self, instance: u32, transform: Affine3A) {
        Control::MoveInstance {
            instance,
            transform,
        }
        .encode(&mut self.transmit);
    }

    /// Control bytes to write, if any.
    pub fn take_transmit(&mut self) -> Option<Bytes> {
        (!self.transmit.is_empty()).then(|| self.transmit.split().freeze())
    }

    /// Frames received since the last call, when capturing (the caller
    /// drains them after every [`on_frames`](Self::on_frames)).
    pub fn take_captured(&mut self) -> Vec<Bytes> {
        std::mem::take(&mut self.captured)
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<ClientEvent> {
        self.events.pop_front()
    }
}
