//! Whole frames: [`decode_frame`] checks a frame against the spec and the
//! receiver's limits and hands back a [`FrameView`] over its messages.

use crate::error::{DecodeError, MessageError};
use crate::limits::Limits;
use crate::wire::compress::Decompressor;
use crate::wire::header::{FrameHeader, HEADER_LEN, frame_checksum};
use crate::wire::message::{Message, Reader};

/// A frame whose header, checksum, compression and message syntax are
/// valid. Only [`decode_frame`] makes one.
#[derive(Clone, Copy, Debug)]
pub struct FrameView<'a> {
    header: FrameHeader,
    payload: &'a [u8],
}

impl<'a> FrameView<'a> {
    /// The header.
    pub fn header(&self) -> &FrameHeader {
        &self.header
    }

    /// The uncompressed payload.
    pub fn payload(&self) -> &'a [u8] {
        self.payload
    }

    /// The messages with their payload offsets, `EndOfFrame` excluded.
    pub fn messages(&self) -> Messages<'a> {
        Messages {
            reader: Reader::new(self.payload),
            index: 0,
            left: self.header.message_count.saturating_sub(1),
        }
    }
}

/// Iterator over the messages of a [`FrameView`].
#[derive(Clone, Debug)]
pub struct Messages<'a> {
    reader: Reader<'a>,
    index: u32,
    left: u32,
}

/// A message with where it stands in the frame.
#[derive(Clone, Copy, Debug)]
pub struct Located<'a> {
    /// Zero-based index of the message.
    pub index: u32,
    /// Offset of its type byte in the payload.
    pub offset: u64,
    /// The message.
    pub message: Message<'a>,
}

impl<'a> Located<'a> {
    /// Wraps a message error with this message's position.
    pub fn error(&self, error: MessageError) -> DecodeError {
        DecodeError::Message {
            index: self.index,
            kind: self.message.kind(),
            offset: self.offset,
            error,
        }
    }
}

impl<'a> Iterator for Messages<'a> {
    type Item = Result<Located<'a>, DecodeError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        let offset = self.reader.pos() as u64;
        let index = self.index;
        self.index += 1;
        Some(match self.reader.message() {
            Ok(message) => Ok(Located {
                index,
                offset,
                message,
            }),
            Err(error) => Err(DecodeError::Message {
                index,
                kind: self.reader.byte_at(offset as usize),
                offset,
                error,
            }),
        })
    }
}

/// Buffers and decompression contexts reused from frame to frame.
#[derive(Debug, Default)]
pub struct Scratch {
    payload: Vec<u8>,
    codec: Decompressor,
}

/// Checks a frame and returns a view of its payload. Compressed payloads
/// are decompressed into `scratch` (reused between calls), whose growth is
/// bounded by `limits.max_payload_bytes`.
pub fn decode_frame<'a>(
    bytes: &'a [u8],
    limits: &Limits,
    scratch: &'a mut Scratch,
) -> Result<FrameView<'a>, DecodeError> {
    if bytes.len() as u64 > limits.max_frame_bytes as u64 {
        return Err(DecodeError::FrameTooLarge {
            len: bytes.len() as u64,
            limit: limits.max_frame_bytes as u64,
        });
    }
    let header = FrameHeader::parse(bytes)?;
    if header.uncompressed_len > limits.max_payload_bytes {
        return Err(DecodeError::PayloadTooLarge {
            len: header.uncompressed_len as u64,
            limit: limits.max_payload_bytes as u64,
        });
    }
    if header.message_count > limits.max_messages {
        return Err(DecodeError::TooManyMessages {
            count: header.message_count,
            limit: limits.max_messages,
        });
    }
    let total = HEADER_LEN as u64 + header.compressed_len as u64;
    if (bytes.len() as u64) < total {
        return Err(DecodeError::Truncated {
            needed: total,
            available: bytes.len() as u64,
        });
    }
    if bytes.len() as u64 > total {
        return Err(DecodeError::TrailingBytes {
            extra: bytes.len() as u64 - total,
        });
    }
    let wire = &bytes[HEADER_LEN..];
    if header.has_checksum {
        let actual = frame_checksum(bytes, wire);
        if actual != header.checksum {
            return Err(DecodeError::Checksum {
                expected: header.checksum,
                actual,
            });
        }
    }
    if !header.compression.decodable() {
        return Err(DecodeError::CompressionUnavailable(header.compression));
    }
    let payload: &'a [u8] = match header.compression {
        crate::Compression::None => wire,
        c => {
            let len = header.uncompressed_len as usize;
            scratch
                .codec
                .decompress_into(c, wire, len, &mut scratch.payload)?;
            &scratch.payload
        }
    };
    let view = FrameView { header, payload };
    check_syntax(&view)?;
    Ok(view)
}

/// Walks every message once: all but the last parse, the last is
/// `EndOfFrame`, nothing follows it.
fn check_syntax(view: &FrameView<'_>) -> Result<(), DecodeError> {
    let mut reader = Reader::new(view.payload);
    for index in 0..view.header.message_count {
        let offset = reader.pos();
        let at = |error| DecodeError::Message {
            index,
            kind: view.payload.get(offset).copied().unwrap_or(0),
            offset: offset as u64,
            error,
        };
        if reader.is_empty() {
            return Err(at(MessageError::MissingEnd));
        }
        let last = index + 1 == view.header.message_count;
        match reader.message().map_err(at)? {
            Message::EndOfFrame if last => {}
            Message::EndOfFrame => return Err(at(MessageError::TrailingBytes)),
            _ if last => return Err(at(MessageError::MissingEnd)),
            _ => {}
        }
    }
    if !reader.is_empty() {
        let offset = reader.pos();
        return Err(DecodeError::Message {
            index: view.header.message_count,
            kind: view.payload[offset],
            offset: offset as u64,
            error: MessageError::TrailingBytes,
        });
    }
    Ok(())
}
