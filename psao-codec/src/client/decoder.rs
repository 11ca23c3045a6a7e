//! The client side of the wire: bytes in, events out, a [`Mirror`] kept in
//! sync. No I/O: the caller hands in each frame as it arrives.

use crate::client::mirror::{Event, Mirror};
use crate::error::DecodeError;
use crate::limits::Limits;
use crate::wire::frame::{Scratch, decode_frame};

/// Decodes frames into a [`Mirror`], enforcing [`Limits`].
///
/// ```
/// use psao_codec::{Decoder, Encoder, EncoderConfig, Event, Limits};
/// let mut encoder = Encoder::new(EncoderConfig::default());
/// let keyframe = encoder.keyframe().finish().unwrap().unwrap();
/// let mut decoder = Decoder::new(Limits::default());
/// let event = decoder.receive(&keyframe.bytes).unwrap();
/// assert_eq!(event, Event::Applied { sequence: 0, keyframe: true });
/// ```
#[derive(Debug, Default)]
pub struct Decoder {
    limits: Limits,
    scratch: Scratch,
    mirror: Mirror,
}

impl Decoder {
    /// A decoder with an empty mirror, waiting for a keyframe.
    pub fn new(limits: Limits) -> Decoder {
        Decoder {
            limits,
            scratch: Scratch::default(),
            mirror: Mirror::new(),
        }
    }

    /// The limits in force.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// The mirror.
    pub fn mirror(&self) -> &Mirror {
        &self.mirror
    }

    /// The mirror, mutably (to take its changes or apply transforms that
    /// arrive outside frames).
    pub fn mirror_mut(&mut self) -> &mut Mirror {
        &mut self.mirror
    }

    /// Decodes one frame and applies it. On error, nothing changed: the
    /// mirror stays at its sequence, and the next delta will report
    /// [`Event::NeedKeyframe`].
    pub fn receive(&mut self, frame: &[u8]) -> Result<Event, DecodeError> {
        let view = decode_frame(frame, &self.limits, &mut self.scratch)?;
        self.mirror.apply(&view, &self.limits)
    }
}
