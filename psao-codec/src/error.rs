//! Typed errors. Every decoder error names what was wrong and where, and has
//! a stable snake_case [`code`](DecodeError::code) that spec/vectors use.

use thiserror::Error;

use crate::wire::compression::Compression;

/// A rule of an instance definition that was broken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum DefError {
    /// origin, cell size, radius or thresholds are NaN or infinite.
    #[error("non-finite float in instance definition")]
    NonFinite,
    /// A cell size component is not positive.
    #[error("cell size must be positive")]
    CellSize,
    /// A dimension is zero, or `31 * dx * dy * dz` exceeds `2^32 - 1`.
    #[error("grid dims must be >= 1 with 31*dx*dy*dz <= 2^32-1")]
    Dims,
    /// `table_log2` above 31, or `2^table_log2 * bucket_capacity` above `2^32 - 1`.
    #[error("table_log2 above 31 or table entries above 2^32-1")]
    TableSize,
    /// Bucket capacity outside `1..=16`.
    #[error("bucket capacity outside 1..=16")]
    BucketCapacity,
    /// Cell capacity outside `1..=8`.
    #[error("cell capacity outside 1..=8")]
    CellCapacity,
    /// Cell pool of 0 cells, or `cell_pool * cell_capacity` above `2^32 - 1`.
    #[error("cell pool must be >= 1 with cell_pool * cell_capacity <= 2^32-1")]
    CellPool,
    /// Unknown point format (known: 0 and 1).
    #[error("unknown point format (known: 0, local space, and 1, bind space)")]
    PointFormat,
    /// Radius not positive, `T_n` outside `[-1, 1]` or `T_d` outside `[0, 1]`.
    #[error("radius must be > 0, T_n in [-1,1], T_d in [0,1]")]
    Reconstruction,
}

/// What was wrong inside one message of a frame.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum MessageError {
    /// The message type byte is not defined by this version.
    #[error("unknown message type 0x{0:02x}")]
    UnknownType(u8),
    /// The message runs past the end of the payload.
    #[error("message truncated")]
    Truncated,
    /// The payload ended (or `message_count` was reached) without `EndOfFrame`.
    #[error("payload does not end with EndOfFrame")]
    MissingEnd,
    /// Bytes follow the `EndOfFrame` message, or `message_count` disagrees.
    #[error("bytes or messages after EndOfFrame")]
    TrailingBytes,
    /// A varint is longer than 5 bytes, above 2^32-1, or not minimal.
    #[error("malformed varint")]
    Varint,
    /// An index list overflows 2^32-1 (indices must strictly increase).
    #[error("index list overflows u32")]
    IndexOverflow,
    /// A slot mask is zero.
    #[error("slot mask is zero")]
    ZeroMask,
    /// A per-bucket entry count or per-cell point count is above its format maximum.
    #[error("count {0} above the format maximum")]
    CountTooLarge(u8),
    /// The instance definition breaks a rule of the spec.
    #[error("invalid instance definition: {0}")]
    Def(#[from] DefError),
    /// A transform holds NaN or infinity.
    #[error("non-finite transform")]
    NonFiniteTransform,
    /// The message names an instance the mirror does not hold.
    #[error("unknown instance {0}")]
    UnknownInstance(u32),
    /// Defining the instance would exceed the receiver's instance limit.
    #[error("instance limit {limit} reached")]
    InstanceLimit {
        /// The configured limit.
        limit: u32,
    },
    /// Defining the instance would exceed a receiver memory or size limit.
    #[error("instance needs {needed} bytes / cells / buckets above the receiver limit {limit}")]
    ResourceLimit {
        /// What the definition asks for.
        needed: u64,
        /// The configured limit.
        limit: u64,
    },
    /// A bucket index at or above the table size.
    #[error("bucket index {0} outside the table")]
    BucketIndex(u32),
    /// A bucket lists more entries than the instance's bucket capacity.
    #[error("bucket {bucket} lists more than the bucket capacity")]
    BucketOverCapacity {
        /// The bucket.
        bucket: u32,
    },
    /// A key names no cell of the grid, or is the empty key.
    #[error("key {0} names no cell of the grid")]
    KeyNotInGrid(u32),
    /// A key does not hash to the bucket it is listed in.
    #[error("key {key} does not hash to bucket {bucket}")]
    KeyWrongBucket {
        /// The key.
        key: u32,
        /// The bucket it was listed in.
        bucket: u32,
    },
    /// The same key twice in one bucket.
    #[error("key {key} twice in bucket {bucket}")]
    DuplicateKey {
        /// The key.
        key: u32,
        /// The bucket.
        bucket: u32,
    },
    /// A cell index at or above the cell pool size.
    #[error("cell index {0} outside the cell pool")]
    CellIndex(u32),
    /// A slot mask or point count names slots beyond the cell capacity.
    #[error("cell {cell}: slots beyond the cell capacity")]
    SlotBeyondCapacity {
        /// The cell.
        cell: u32,
    },
    /// A word that is neither 0 nor a valid allocated word (normal code 15).
    #[error("cell {cell}: invalid point word 0x{word:08x}")]
    InvalidWord {
        /// The cell.
        cell: u32,
        /// The word.
        word: u32,
    },
    /// After the update an allocated word follows an unallocated one.
    #[error("cell {cell}: allocated point after an empty slot (compaction)")]
    Compaction {
        /// The cell.
        cell: u32,
    },
    /// An AO delta targets an unallocated slot.
    #[error("cell {cell}: AO update to empty slot {slot}")]
    AoToEmptySlot {
        /// The cell.
        cell: u32,
        /// The slot.
        slot: u8,
    },
}

/// What was wrong with a compressed payload (error class `decompress`,
/// spec/wire-format.md 3.2). Offsets count from the first payload byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum DecompressFault {
    /// zstd: the payload holds no zstd frame (it is empty, or made only of
    /// skippable frames).
    #[error("no zstd frame in the payload")]
    NoFrame,
    /// zstd: the bytes at `offset` start neither a zstd frame nor a
    /// skippable frame (legacy zstd formats included), or end inside a
    /// frame header.
    #[error("no zstd or skippable frame header at offset {offset}")]
    NotAFrame {
        /// Where the frame should start.
        offset: u32,
    },
    /// zstd: the frame header's reserved bit is set.
    #[error("reserved bit set in the zstd frame header at offset {offset}")]
    ReservedBit {
        /// Where the frame starts.
        offset: u32,
    },
    /// zstd: the frame names a dictionary (none is defined).
    #[error("zstd frame at offset {offset} needs dictionary {id}")]
    Dictionary {
        /// Where the frame starts.
        offset: u32,
        /// The `Dictionary_ID`.
        id: u32,
    },
    /// zstd: the frame's `Window_Size` is above 2^27 bytes.
    #[error("zstd frame at offset {offset} has a window of {window} bytes, above 2^27")]
    Window {
        /// Where the frame starts.
        offset: u32,
        /// Its `Window_Size` in bytes.
        window: u64,
    },
    /// LZ4: the block breaks an end-of-block rule (the last sequence holds
    /// only literals, at least 5 of them after a match, and the last match
    /// starts at least 12 bytes before the end).
    #[error("LZ4 block breaks the end-of-block rules")]
    EndOfBlock,
    /// The data is corrupt in its format (truncated, a bad offset, a block
    /// zstd or LZ4 cannot decode, a content size or checksum that differs).
    #[error("corrupt compressed data")]
    Corrupt,
    /// The data decompresses to another length than `uncompressed_len`.
    #[error("decompresses to another length than uncompressed_len")]
    Length,
}

/// Why a frame was rejected. The mirror is unchanged after any of these.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Fewer bytes than the header, or than the header's lengths announce.
    #[error("frame truncated: need {needed} bytes, have {available}")]
    Truncated {
        /// Bytes the header requires.
        needed: u64,
        /// Bytes present.
        available: u64,
    },
    /// More bytes than the header announces.
    #[error("frame has {extra} bytes after its payload")]
    TrailingBytes {
        /// Extra bytes.
        extra: u64,
    },
    /// The first four bytes are not `PSAO`.
    #[error("bad magic")]
    BadMagic,
    /// A version this decoder does not speak.
    #[error("unsupported version {0}")]
    UnsupportedVersion(u8),
    /// A reserved header field or flag bit is not zero, or fields contradict.
    #[error("invalid header field `{0}`")]
    HeaderField(&'static str),
    /// Unknown compression id.
    #[error("unknown compression id {0}")]
    UnknownCompression(u8),
    /// A compression this build leaves out (cargo feature off).
    #[error("compression {0:?} not compiled in")]
    CompressionUnavailable(Compression),
    /// The frame is larger than the receiver's limit.
    #[error("frame of {len} bytes above the limit {limit}")]
    FrameTooLarge {
        /// Frame length.
        len: u64,
        /// Limit.
        limit: u64,
    },
    /// The announced uncompressed payload is larger than the receiver's limit.
    #[error("payload of {len} bytes above the limit {limit}")]
    PayloadTooLarge {
        /// Announced length.
        len: u64,
        /// Limit.
        limit: u64,
    },
    /// The announced message count is above the receiver's limit.
    #[error("{count} messages above the limit {limit}")]
    TooManyMessages {
        /// Announced count.
        count: u32,
        /// Limit.
        limit: u32,
    },
    /// CRC-32 mismatch.
    #[error("checksum mismatch: header 0x{expected:08x}, computed 0x{actual:08x}")]
    Checksum {
        /// In the header.
        expected: u32,
        /// Computed.
        actual: u32,
    },
    /// The compressed payload is not valid in its format (spec 3.2), or
    /// decompresses to another length than `uncompressed_len`.
    #[error("{compression:?} payload rejected: {fault}")]
    Decompress {
        /// The header's compression.
        compression: Compression,
        /// What was wrong with the data.
        fault: DecompressFault,
    },
    /// A message is malformed or cannot be applied.
    #[error("message {index} (type 0x{kind:02x}) at payload offset {offset}: {error}")]
    Message {
        /// Zero-based message index.
        index: u32,
        /// Message type byte.
        kind: u8,
        /// Offset of the message's type byte in the uncompressed payload.
        offset: u64,
        /// What was wrong.
        error: MessageError,
    },
}

impl DecodeError {
    /// Stable identifier of the error class, as used in spec/vectors.
    pub fn code(&self) -> &'static str {
        match self {
            DecodeError::Truncated { .. } => "truncated",
            DecodeError::TrailingBytes { .. } => "trailing_bytes",
            DecodeError::BadMagic => "bad_magic",
            DecodeError::UnsupportedVersion(_) => "unsupported_version",
            DecodeError::HeaderField(_) => "header_field",
            DecodeError::UnknownCompression(_) => "unknown_compression",
            DecodeError::CompressionUnavailable(_) => "compression_unavailable",
            DecodeError::FrameTooLarge { .. } => "frame_too_large",
            DecodeError::PayloadTooLarge { .. } => "payload_too_large",
            DecodeError::TooManyMessages { .. } => "too_many_messages",
            DecodeError::Checksum { .. } => "checksum",
            DecodeError::Decompress { .. } => "decompress",
            DecodeError::Message { error, .. } => error.code(),
        }
    }
}

impl MessageError {
    /// Stable identifier of the error class, as used in spec/vectors.
    pub fn code(&self) -> &'static str {
        match self {
            MessageError::UnknownType(_) => "unknown_message_type",
            MessageError::Truncated => "message_truncated",
            MessageError::MissingEnd => "missing_end",
            MessageError::TrailingBytes => "after_end",
            MessageError::Varint => "varint",
            MessageError::IndexOverflow => "index_overflow",
            MessageError::ZeroMask => "zero_mask",
            MessageError::CountTooLarge(_) => "count_too_large",
            MessageError::Def(_) => "invalid_definition",
            MessageError::NonFiniteTransform => "non_finite_transform",
            MessageError::UnknownInstance(_) => "unknown_instance",
            MessageError::InstanceLimit { .. } => "instance_limit",
            MessageError::ResourceLimit { .. } => "resource_limit",
            MessageError::BucketIndex(_) => "bucket_index",
            MessageError::BucketOverCapacity { .. } => "bucket_over_capacity",
            MessageError::KeyNotInGrid(_) => "key_not_in_grid",
            MessageError::KeyWrongBucket { .. } => "key_wrong_bucket",
            MessageError::DuplicateKey { .. } => "duplicate_key",
            MessageError::CellIndex(_) => "cell_index",
            MessageError::SlotBeyondCapacity { .. } => "slot_beyond_capacity",
            MessageError::InvalidWord { .. } => "invalid_word",
            MessageError::Compaction { .. } => "compaction",
            MessageError::AoToEmptySlot { .. } => "ao_to_empty_slot",
        }
    }
}

/// Errors of the server-side [`GridTable`](crate::GridTable) and [`Encoder`](crate::Encoder).
#[derive(Clone, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// The instance definition breaks a rule of the spec.
    #[error("invalid instance definition: {0}")]
    Def(#[from] DefError),
    /// A point id beyond the table's point capacity.
    #[error("point id {id} above the table's limit {limit}")]
    PointId {
        /// The id.
        id: u32,
        /// The table's `max_points`.
        limit: u32,
    },
    /// A keyframe was asked for while the table holds changes not yet sent
    /// in a delta: the keyframe would not match its sequence number.
    #[error("instance {0} has unsent changes; encode the delta frame before a keyframe")]
    PendingChanges(u32),
    /// The frame would exceed the spec's 2^32-1 byte payload.
    #[error("frame payload above 2^32-1 bytes")]
    FrameTooLarge,
    /// The frame would exceed a limit of its receivers
    /// ([`EncoderConfig::limits`](crate::EncoderConfig::limits)).
    #[error("{what} {size} above the receivers' limit {limit}")]
    ReceiverLimit {
        /// Which limit.
        what: &'static str,
        /// The frame's size in that unit.
        size: u64,
        /// The limit.
        limit: u64,
    },
    /// The compression is not compiled in.
    #[error("compression {0:?} not compiled in")]
    CompressionUnavailable(Compression),
    /// The compressor failed.
    #[error("compressor failed: {0}")]
    Compressor(String),
}
