//! Frame records on the frame stream (spec/session.md, section 4): a
//! `u32` length, then one frame.

use bytes::{Buf, Bytes, BytesMut};

use crate::codes::SessionError;

/// Smallest frame (its header).
pub const MIN_FRAME: u32 = 32;

/// The 4-byte length prefix of a record holding `frame`.
pub fn record_prefix(frame: &[u8]) -> [u8; 4] {
    (frame.len() as u32).to_le_bytes()
}

/// Reads frame records out of a byte stream as it arrives, never holding
/// more than `4 + max_frame_bytes` bytes.
#[derive(Debug)]
pub struct RecordReader {
    max_frame_bytes: u32,
    buf: BytesMut,
    want: Option<usize>,
}

impl RecordReader {
    /// A reader refusing records longer than `max_frame_bytes`.
    pub fn new(max_frame_bytes: u32) -> RecordReader {
        RecordReader {
            max_frame_bytes,
            buf: BytesMut::new(),
            want: None,
        }
    }

    /// Lowers the largest record accepted from now on (after `WELCOME`).
    pub fn limit(&mut self, max_frame_bytes: u32) {
        self.max_frame_bytes = self.max_frame_bytes.min(max_frame_bytes);
    }

    /// Takes bytes off `input` and returns the next whole frame, if any.
    /// Call again while it returns frames and `input` is not empty.
    pub fn read(&mut self, input: &mut &[u8]) -> Result<Option<Bytes>, SessionError> {
        let want = match self.want {
            Some(w) => w,
            None => {
                let take = (4 - self.buf.len()).min(input.len());
                self.buf.extend_from_slice(&input[..take]);
                input.advance(take);
                if self.buf.len() < 4 {
                    return Ok(None);
                }
                let len = u32::from_le_bytes([self.buf[0], self.buf[1], self.buf[2], self.buf[3]]);
                if !(MIN_FRAME..=self.max_frame_bytes).contains(&len) {
                    return Err(SessionError::FrameRecordSize {
                        length: len,
                        min: MIN_FRAME,
                        max: self.max_frame_bytes,
                    });
                }
                self.buf.clear();
                self.buf.reserve(len as usize);
                self.want = Some(len as usize);
                len as usize
            }
        };
        let take = (want - self.buf.len()).min(input.len());
        self.buf.extend_from_slice(&input[..take]);
        input.advance(take);
        if self.buf.len() < want {
            return Ok(None);
        }
        self.want = None;
        Ok(Some(self.buf.split().freeze()))
    }
}
