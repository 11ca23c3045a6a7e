//! The bytes of spec/wire-format.md: the frame header, the message
//! payload (its types, layouts and index lists), compression, the point
//! word and sequence arithmetic. Both halves of the codec read and write
//! through here. Most users need only the crate root (encoder, decoder,
//! mirror); a fuzzer, a capture inspector or a third-party decoder's tests
//! parse frames with what is here.

pub(crate) mod compress;
pub(crate) mod compression;
pub(crate) mod frame;
pub(crate) mod header;
#[cfg(feature = "lz4")]
pub(crate) mod lz4_block;
pub(crate) mod message;
pub mod point;
pub mod sequence;
#[cfg(any(feature = "zstd", feature = "zstd-pure"))]
pub(crate) mod zstd_frames;

pub use frame::{FrameView, Located, Messages, Scratch, decode_frame};
pub use header::{FLAG_CHECKSUM, FLAG_KEYFRAME, FrameHeader, HEADER_LEN, MAGIC, VERSION};
pub use message::{BucketsMsg, CellsMsg, IndexIter, IndexList, Message, PlanarU32, kind};

/// `size` bytes of runs and noise (both a compressor's literal and match
/// paths), deterministic for a seed: test payloads for the compressions.
#[cfg(all(test, feature = "zstd"))]
pub(crate) fn runs_and_noise(size: usize, mut state: u32) -> Vec<u8> {
    (0..size)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            if i % 64 < 40 {
                (i / 64) as u8
            } else {
                state as u8
            }
        })
        .collect()
}
