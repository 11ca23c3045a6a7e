//! The compressions of the spec (header byte 6): ids, and which this
//! build has. The calls into zstd and lz4_flex are in `compress.rs`.

/// Payload compression of a frame (header byte 6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Compression {
    /// Id 0: the payload is stored as it is.
    None,
    /// Id 1: one LZ4 block (no LZ4 frame header).
    Lz4,
    /// Id 2: one or more zstd frames (RFC 8878), no dictionary.
    Zstd,
}

impl Compression {
    /// The id on the wire.
    pub fn id(self) -> u8 {
        match self {
            Compression::None => 0,
            Compression::Lz4 => 1,
            Compression::Zstd => 2,
        }
    }

    /// Whether this build can compress and decompress it.
    pub fn available(self) -> bool {
        match self {
            Compression::None => true,
            Compression::Lz4 => cfg!(feature = "lz4"),
            Compression::Zstd => cfg!(feature = "zstd"),
        }
    }

    /// Whether this build can decompress it: as [`Compression::available`],
    /// and zstd also with feature `zstd-pure` (ruzstd, decoding only).
    pub fn decodable(self) -> bool {
        self.available() || (self == Compression::Zstd && cfg!(feature = "zstd-pure"))
    }
}
