//! The 32-byte frame header (spec/wire-format.md, "Frame header").

use crate::error::DecodeError;
use crate::wire::compression::Compression;

/// `PSAO` in ASCII.
pub const MAGIC: [u8; 4] = *b"PSAO";
/// The wire format version this crate speaks.
pub const VERSION: u8 = 1;
/// Header length in bytes.
pub const HEADER_LEN: usize = 32;
/// Flag bit 0: the frame is a keyframe.
pub const FLAG_KEYFRAME: u8 = 1;
/// Flag bit 1: the checksum field holds a CRC-32 of the frame.
pub const FLAG_CHECKSUM: u8 = 2;
const FLAGS_KNOWN: u8 = FLAG_KEYFRAME | FLAG_CHECKSUM;

/// A parsed frame header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameHeader {
    /// A keyframe replaces the whole mirror; a delta applies to `base_sequence`.
    pub keyframe: bool,
    /// Whether `checksum` is a CRC-32 of the frame.
    pub has_checksum: bool,
    /// Compression of the payload.
    pub compression: Compression,
    /// Sequence number of the state after this frame.
    pub sequence: u32,
    /// The sequence a delta applies to (equal to `sequence` in a keyframe).
    pub base_sequence: u32,
    /// Number of messages, `EndOfFrame` included.
    pub message_count: u32,
    /// Payload length after decompression.
    pub uncompressed_len: u32,
    /// Payload length on the wire.
    pub compressed_len: u32,
    /// CRC-32 (IEEE 802.3, as zlib) of header bytes 0..28 then the payload
    /// as sent; 0 when `has_checksum` is false.
    pub checksum: u32,
}

impl FrameHeader {
    /// Writes the header (with its checksum field as stored in `self`).
    pub fn write(&self, out: &mut [u8; HEADER_LEN]) {
        out[0..4].copy_from_slice(&MAGIC);
        out[4] = VERSION;
        out[5] =
            ((self.keyframe as u8) * FLAG_KEYFRAME) | ((self.has_checksum as u8) * FLAG_CHECKSUM);
        out[6] = self.compression.id();
        out[7] = 0;
        out[8..12].copy_from_slice(&self.sequence.to_le_bytes());
        out[12..16].copy_from_slice(&self.base_sequence.to_le_bytes());
        out[16..20].copy_from_slice(&self.message_count.to_le_bytes());
        out[20..24].copy_from_slice(&self.uncompressed_len.to_le_bytes());
        out[24..28].copy_from_slice(&self.compressed_len.to_le_bytes());
        out[28..32].copy_from_slice(&self.checksum.to_le_bytes());
    }

    /// Parses and checks the fixed rules of a header (not the limits, the
    /// total length or the checksum, which need the rest of the frame).
    pub fn parse(bytes: &[u8]) -> Result<FrameHeader, DecodeError> {
        let Some(h) = bytes.first_chunk::<HEADER_LEN>() else {
            return Err(DecodeError::Truncated {
                needed: HEADER_LEN as u64,
                available: bytes.len() as u64,
            });
        };
        if h[0..4] != MAGIC {
            return Err(DecodeError::BadMagic);
        }
        if h[4] != VERSION {
            return Err(DecodeError::UnsupportedVersion(h[4]));
        }
        let flags = h[5];
        if flags & !FLAGS_KNOWN != 0 {
            return Err(DecodeError::HeaderField("flags"));
        }
        let compression = Compression::from_id(h[6])?;
        if h[7] != 0 {
            return Err(DecodeError::HeaderField("reserved"));
        }
        let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        let header = FrameHeader {
            keyframe: flags & FLAG_KEYFRAME != 0,
            has_checksum: flags & FLAG_CHECKSUM != 0,
            compression,
            sequence: word(8),
            base_sequence: word(12),
            message_count: word(16),
            uncompressed_len: word(20),
            compressed_len: word(24),
            checksum: word(28),
        };
        if header.keyframe && header.base_sequence != header.sequence {
            return Err(DecodeError::HeaderField("base_sequence"));
        }
        if !header.keyframe
            && !crate::wire::sequence::is_newer(header.sequence, header.base_sequence)
        {
            return Err(DecodeError::HeaderField("base_sequence"));
        }
        if header.message_count == 0 {
            return Err(DecodeError::HeaderField("message_count"));
        }
        if compression == Compression::None && header.compressed_len != header.uncompressed_len {
            return Err(DecodeError::HeaderField("compressed_len"));
        }
        if !header.has_checksum && header.checksum != 0 {
            return Err(DecodeError::HeaderField("checksum"));
        }
        Ok(header)
    }
}

/// CRC-32 of a frame: header bytes 0..28, then the payload as sent.
pub fn frame_checksum(header: &[u8], payload: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&header[..28]);
    h.update(payload);
    h.finalize()
}
