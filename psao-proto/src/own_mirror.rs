//! A server's mirror of its own stream, sans-IO: every frame and keyframe
//! it sends is applied to it, so it can say what digest (spec/session.md
//! 3.8) a client in sync holds after each. The reference QUIC server and
//! the MoQ publisher (psao-moq) both keep one.

use psao_codec::{Decoder, EncodedFrame, Event, Limits};

use crate::source::SourceInfo;

/// The server's own mirror of what it streamed.
#[derive(Debug)]
pub struct OwnMirror {
    decoder: Decoder,
}

/// Why a frame of the server's own did not apply to its mirror (a bug of
/// the source: the mirror is emptied and waits for the next keyframe).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the server's own frame {sequence} did not apply to its mirror: {what}")]
pub struct OwnFrameRefused {
    /// The frame's sequence.
    pub sequence: u32,
    /// What the decoder said.
    pub what: String,
}

impl OwnMirror {
    /// An empty mirror sized for `info`'s frames (its mirror bytes, at
    /// least 1 GiB).
    pub fn new(info: &SourceInfo) -> OwnMirror {
        OwnMirror {
            decoder: Decoder::new(Limits {
                max_frame_bytes: info.max_frame_bytes,
                max_payload_bytes: info.max_payload_bytes,
                max_mirror_bytes: info.mirror_bytes.max(1 << 30),
                ..Limits::default()
            }),
        }
    }

    /// Applies a frame the server sends. A delta before the first keyframe
    /// (no client asked for one yet) leaves the mirror empty and is not an
    /// error; a frame that fails to apply empties the mirror.
    pub fn apply(&mut self, frame: &EncodedFrame) -> Result<(), OwnFrameRefused> {
        match self.decoder.receive(&frame.bytes) {
            Ok(Event::Applied { .. }) | Ok(Event::Stale { .. }) => Ok(()),
            Ok(Event::NeedKeyframe { .. }) if self.decoder.mirror().sequence().is_none() => Ok(()),
            other => {
                self.decoder = Decoder::new(*self.decoder.limits());
                Err(OwnFrameRefused {
                    sequence: frame.sequence,
                    what: format!("{other:?}"),
                })
            }
        }
    }

    /// The sequence of the state it holds (`None` before the first
    /// keyframe).
    pub fn sequence(&self) -> Option<u32> {
        self.decoder.mirror().sequence()
    }

    /// The digest of the state it holds (spec/wire-format.md 7.5; `None`
    /// before the first keyframe).
    pub fn digest(&self) -> Option<u32> {
        self.decoder.mirror().digest()
    }
}
