//! Results: every call returns a [`psao_result`]; a failure's detailed
//! message is kept by the object it happened on (`psao_*_last_error`).
//! Decode errors map one to one onto the spec's error classes.

use std::ffi::{CStr, c_char};

use psao_codec::{DecodeError, EncodeError, MessageError};

/// What a call did: `PSAO_OK`, or why it failed. Codes 100 to 199 are the
/// error classes of spec/wire-format.md (the names `psao_result_name`
/// gives are the spec's), 200 and up the encoder's, below 100 the C
/// boundary's. Values are stable: new codes are only ever added.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_result {
    /// Success.
    PSAO_OK = 0,
    /// A pointer argument that must not be NULL was NULL.
    PSAO_ERROR_NULL_POINTER = 1,
    /// An output buffer is too short: `*len` holds the length needed and nothing else was written.
    PSAO_ERROR_BUFFER_TOO_SHORT = 2,
    /// An argument is out of its domain (a flag other than 0 or 1, an unknown compression, a zstd level outside zstd's range, a misaligned array or one too long to address, a world-space lookup of a bind-space instance, changes in a keyframe); the object's last error names it.
    PSAO_ERROR_INVALID_ARGUMENT = 3,
    /// The instance asked for is not in the mirror.
    PSAO_ERROR_NOT_FOUND = 4,
    /// The decoder has no keyframe yet (no sequence, no digest).
    PSAO_ERROR_NO_STATE = 5,
    /// A range beyond the instance's arrays.
    PSAO_ERROR_OUT_OF_RANGE = 6,
    /// A frame is being built (or a finished one waits to be collected): finish or abort it first.
    PSAO_ERROR_FRAME_OPEN = 7,
    /// No frame is being built: call `psao_encoder_begin` first.
    PSAO_ERROR_NO_FRAME_OPEN = 8,
    /// A bug inside psao panicked; it was caught at the boundary. The object is poisoned: every later call on it returns this code; free it.
    PSAO_ERROR_PANIC = 9,
    /// The frame is shorter than its header, or than the lengths it announces. Spec error class `truncated`.
    PSAO_ERROR_TRUNCATED = 100,
    /// Bytes follow the frame's payload. Spec error class `trailing_bytes`.
    PSAO_ERROR_TRAILING_BYTES = 101,
    /// The first four bytes are not `PSAO`. Spec error class `bad_magic`.
    PSAO_ERROR_BAD_MAGIC = 102,
    /// A wire version this library does not speak. Spec error class `unsupported_version`.
    PSAO_ERROR_UNSUPPORTED_VERSION = 103,
    /// A reserved header field or flag is not zero, or header fields contradict. Spec error class `header_field`.
    PSAO_ERROR_HEADER_FIELD = 104,
    /// The compression id is not defined. Spec error class `unknown_compression`.
    PSAO_ERROR_UNKNOWN_COMPRESSION = 105,
    /// The compression is not compiled into this library. Spec error class `compression_unavailable`.
    PSAO_ERROR_COMPRESSION_UNAVAILABLE = 106,
    /// The frame is larger than `max_frame_bytes`. Spec error class `frame_too_large`.
    PSAO_ERROR_FRAME_TOO_LARGE = 107,
    /// The announced payload is larger than `max_payload_bytes`. Spec error class `payload_too_large`.
    PSAO_ERROR_PAYLOAD_TOO_LARGE = 108,
    /// The announced message count is above `max_messages`. Spec error class `too_many_messages`.
    PSAO_ERROR_TOO_MANY_MESSAGES = 109,
    /// The frame's CRC-32 does not match. Spec error class `checksum`.
    PSAO_ERROR_CHECKSUM = 110,
    /// The compressed payload is invalid in its format. Spec error class `decompress`.
    PSAO_ERROR_DECOMPRESS = 111,
    /// A message type this version does not define. Spec error class `unknown_message_type`.
    PSAO_ERROR_UNKNOWN_MESSAGE_TYPE = 112,
    /// A message runs past the end of the payload. Spec error class `message_truncated`.
    PSAO_ERROR_MESSAGE_TRUNCATED = 113,
    /// The payload does not end with EndOfFrame. Spec error class `missing_end`.
    PSAO_ERROR_MISSING_END = 114,
    /// Bytes or messages follow EndOfFrame. Spec error class `after_end`.
    PSAO_ERROR_AFTER_END = 115,
    /// A malformed varint. Spec error class `varint`.
    PSAO_ERROR_VARINT = 116,
    /// An index list overflows 2^32-1. Spec error class `index_overflow`.
    PSAO_ERROR_INDEX_OVERFLOW = 117,
    /// A slot mask is zero. Spec error class `zero_mask`.
    PSAO_ERROR_ZERO_MASK = 118,
    /// A count above its format maximum. Spec error class `count_too_large`.
    PSAO_ERROR_COUNT_TOO_LARGE = 119,
    /// An instance definition breaks a rule of the spec. Spec error class `invalid_definition`.
    PSAO_ERROR_INVALID_DEFINITION = 120,
    /// A transform holds NaN or infinity. Spec error class `non_finite_transform`.
    PSAO_ERROR_NON_FINITE_TRANSFORM = 121,
    /// A message (or `psao_decoder_apply_transform`) names an instance the mirror does not hold. Spec error class `unknown_instance`.
    PSAO_ERROR_UNKNOWN_INSTANCE = 122,
    /// Defining the instance would exceed `max_instances`. Spec error class `instance_limit`.
    PSAO_ERROR_INSTANCE_LIMIT = 123,
    /// The instance needs more than `max_table_log2`, `max_cell_pool` or `max_mirror_bytes` allow. Spec error class `resource_limit`.
    PSAO_ERROR_RESOURCE_LIMIT = 124,
    /// A bucket index outside the table. Spec error class `bucket_index`.
    PSAO_ERROR_BUCKET_INDEX = 125,
    /// A bucket lists more entries than its capacity. Spec error class `bucket_over_capacity`.
    PSAO_ERROR_BUCKET_OVER_CAPACITY = 126,
    /// A key names no cell of the grid. Spec error class `key_not_in_grid`.
    PSAO_ERROR_KEY_NOT_IN_GRID = 127,
    /// A key does not hash to the bucket it is listed in. Spec error class `key_wrong_bucket`.
    PSAO_ERROR_KEY_WRONG_BUCKET = 128,
    /// The same key twice in one bucket. Spec error class `duplicate_key`.
    PSAO_ERROR_DUPLICATE_KEY = 129,
    /// A cell index outside the cell pool. Spec error class `cell_index`.
    PSAO_ERROR_CELL_INDEX = 130,
    /// Slots beyond the cell capacity. Spec error class `slot_beyond_capacity`.
    PSAO_ERROR_SLOT_BEYOND_CAPACITY = 131,
    /// A point word that is neither 0 nor a valid allocated word. Spec error class `invalid_word`.
    PSAO_ERROR_INVALID_WORD = 132,
    /// An allocated point after an empty slot. Spec error class `compaction`.
    PSAO_ERROR_COMPACTION = 133,
    /// An AO update to an empty slot. Spec error class `ao_to_empty_slot`.
    PSAO_ERROR_AO_TO_EMPTY_SLOT = 134,
    /// A point id at or above the table's `max_points`.
    PSAO_ERROR_POINT_ID = 200,
    /// A keyframe snapshot of a table with changes not yet sent in a delta.
    PSAO_ERROR_PENDING_CHANGES = 201,
    /// The frame would exceed the format's 2^32-1 byte payload.
    PSAO_ERROR_ENCODE_FRAME_TOO_LARGE = 202,
    /// The frame would exceed a limit of the receivers (the encoder's limits).
    PSAO_ERROR_RECEIVER_LIMIT = 203,
    /// The compressor failed.
    PSAO_ERROR_COMPRESSOR_FAILED = 204,
}

/// Every result with its stable name (for decode errors, the spec's error class).
pub(crate) const NAMES: &[(psao_result, &CStr)] = &[
    (psao_result::PSAO_OK, c"ok"),
    (psao_result::PSAO_ERROR_NULL_POINTER, c"null_pointer"),
    (
        psao_result::PSAO_ERROR_BUFFER_TOO_SHORT,
        c"buffer_too_short",
    ),
    (
        psao_result::PSAO_ERROR_INVALID_ARGUMENT,
        c"invalid_argument",
    ),
    (psao_result::PSAO_ERROR_NOT_FOUND, c"not_found"),
    (psao_result::PSAO_ERROR_NO_STATE, c"no_state"),
    (psao_result::PSAO_ERROR_OUT_OF_RANGE, c"out_of_range"),
    (psao_result::PSAO_ERROR_FRAME_OPEN, c"frame_open"),
    (psao_result::PSAO_ERROR_NO_FRAME_OPEN, c"no_frame_open"),
    (psao_result::PSAO_ERROR_PANIC, c"panic"),
    (psao_result::PSAO_ERROR_TRUNCATED, c"truncated"),
    (psao_result::PSAO_ERROR_TRAILING_BYTES, c"trailing_bytes"),
    (psao_result::PSAO_ERROR_BAD_MAGIC, c"bad_magic"),
    (
        psao_result::PSAO_ERROR_UNSUPPORTED_VERSION,
        c"unsupported_version",
    ),
    (psao_result::PSAO_ERROR_HEADER_FIELD, c"header_field"),
    (
        psao_result::PSAO_ERROR_UNKNOWN_COMPRESSION,
        c"unknown_compression",
    ),
    (
        psao_result::PSAO_ERROR_COMPRESSION_UNAVAILABLE,
        c"compression_unavailable",
    ),
    (psao_result::PSAO_ERROR_FRAME_TOO_LARGE, c"frame_too_large"),
    (
        psao_result::PSAO_ERROR_PAYLOAD_TOO_LARGE,
        c"payload_too_large",
    ),
    (
        psao_result::PSAO_ERROR_TOO_MANY_MESSAGES,
        c"too_many_messages",
    ),
    (psao_result::PSAO_ERROR_CHECKSUM, c"checksum"),
    (psao_result::PSAO_ERROR_DECOMPRESS, c"decompress"),
    (
        psao_result::PSAO_ERROR_UNKNOWN_MESSAGE_TYPE,
        c"unknown_message_type",
    ),
    (
        psao_result::PSAO_ERROR_MESSAGE_TRUNCATED,
        c"message_truncated",
    ),
    (psao_result::PSAO_ERROR_MISSING_END, c"missing_end"),
    (psao_result::PSAO_ERROR_AFTER_END, c"after_end"),
    (psao_result::PSAO_ERROR_VARINT, c"varint"),
    (psao_result::PSAO_ERROR_INDEX_OVERFLOW, c"index_overflow"),
    (psao_result::PSAO_ERROR_ZERO_MASK, c"zero_mask"),
    (psao_result::PSAO_ERROR_COUNT_TOO_LARGE, c"count_too_large"),
    (
        psao_result::PSAO_ERROR_INVALID_DEFINITION,
        c"invalid_definition",
    ),
    (
        psao_result::PSAO_ERROR_NON_FINITE_TRANSFORM,
        c"non_finite_transform",
    ),
    (
        psao_result::PSAO_ERROR_UNKNOWN_INSTANCE,
        c"unknown_instance",
    ),
    (psao_result::PSAO_ERROR_INSTANCE_LIMIT, c"instance_limit"),
    (psao_result::PSAO_ERROR_RESOURCE_LIMIT, c"resource_limit"),
    (psao_result::PSAO_ERROR_BUCKET_INDEX, c"bucket_index"),
    (
        psao_result::PSAO_ERROR_BUCKET_OVER_CAPACITY,
        c"bucket_over_capacity",
    ),
    (psao_result::PSAO_ERROR_KEY_NOT_IN_GRID, c"key_not_in_grid"),
    (
        psao_result::PSAO_ERROR_KEY_WRONG_BUCKET,
        c"key_wrong_bucket",
    ),
    (psao_result::PSAO_ERROR_DUPLICATE_KEY, c"duplicate_key"),
    (psao_result::PSAO_ERROR_CELL_INDEX, c"cell_index"),
    (
        psao_result::PSAO_ERROR_SLOT_BEYOND_CAPACITY,
        c"slot_beyond_capacity",
    ),
    (psao_result::PSAO_ERROR_INVALID_WORD, c"invalid_word"),
    (psao_result::PSAO_ERROR_COMPACTION, c"compaction"),
    (
        psao_result::PSAO_ERROR_AO_TO_EMPTY_SLOT,
        c"ao_to_empty_slot",
    ),
    (psao_result::PSAO_ERROR_POINT_ID, c"point_id"),
    (psao_result::PSAO_ERROR_PENDING_CHANGES, c"pending_changes"),
    (
        psao_result::PSAO_ERROR_ENCODE_FRAME_TOO_LARGE,
        c"encode_frame_too_large",
    ),
    (psao_result::PSAO_ERROR_RECEIVER_LIMIT, c"receiver_limit"),
    (
        psao_result::PSAO_ERROR_COMPRESSOR_FAILED,
        c"compressor_failed",
    ),
];

impl psao_result {
    /// The result whose stable name is `name` (a spec error class for
    /// decode errors).
    pub fn from_name(name: &str) -> Option<psao_result> {
        NAMES
            .iter()
            .find(|(_, n)| n.to_bytes() == name.as_bytes())
            .map(|&(r, _)| r)
    }

    /// The stable name: `ok`, a spec error class such as `truncated`, or
    /// a boundary or encoder name such as `buffer_too_short`.
    pub fn name(self) -> &'static str {
        self.c_name().to_str().unwrap_or("unknown")
    }

    fn c_name(self) -> &'static CStr {
        NAMES
            .iter()
            .find(|&&(r, _)| r == self)
            .map_or(c"unknown", |&(_, n)| n)
    }

    /// The result with this numeric value, if one is defined.
    pub fn from_u32(value: u32) -> Option<psao_result> {
        NAMES.iter().map(|&(r, _)| r).find(|&r| r as u32 == value)
    }
}

/// A failed call: its code and the message its object keeps.
#[derive(Debug)]
pub(crate) struct Failure {
    pub(crate) code: psao_result,
    pub(crate) message: String,
}

impl Failure {
    pub(crate) fn new(code: psao_result, message: impl Into<String>) -> Failure {
        Failure {
            code,
            message: message.into(),
        }
    }

    /// A NULL pointer where `what` must point somewhere.
    pub(crate) fn null(what: &str) -> Failure {
        Failure::new(
            psao_result::PSAO_ERROR_NULL_POINTER,
            format!("`{what}` is NULL"),
        )
    }

    /// An argument outside its domain.
    pub(crate) fn invalid(message: impl Into<String>) -> Failure {
        Failure::new(psao_result::PSAO_ERROR_INVALID_ARGUMENT, message)
    }
}

/// A spec error class name to its code. Every class the codec names has
/// a code (a test checks the list against the codec's), so the fallback is
/// for a class a newer codec might add before this list learns it.
fn class(code: &str) -> psao_result {
    psao_result::from_name(code).unwrap_or(psao_result::PSAO_ERROR_INVALID_ARGUMENT)
}

impl From<DecodeError> for Failure {
    fn from(e: DecodeError) -> Failure {
        Failure::new(class(e.code()), e.to_string())
    }
}

impl From<MessageError> for Failure {
    fn from(e: MessageError) -> Failure {
        Failure::new(class(e.code()), e.to_string())
    }
}

impl From<EncodeError> for Failure {
    fn from(e: EncodeError) -> Failure {
        use psao_result::*;
        let code = match &e {
            EncodeError::Def(_) => PSAO_ERROR_INVALID_DEFINITION,
            EncodeError::PointId { .. } => PSAO_ERROR_POINT_ID,
            EncodeError::PendingChanges(_) => PSAO_ERROR_PENDING_CHANGES,
            EncodeError::FrameTooLarge => PSAO_ERROR_ENCODE_FRAME_TOO_LARGE,
            EncodeError::ReceiverLimit { .. } => PSAO_ERROR_RECEIVER_LIMIT,
            EncodeError::CompressionUnavailable(_) => PSAO_ERROR_COMPRESSION_UNAVAILABLE,
            EncodeError::Compressor(_) => PSAO_ERROR_COMPRESSOR_FAILED,
            // An error a newer codec adds before this list learns it.
            _ => PSAO_ERROR_INVALID_ARGUMENT,
        };
        Failure::new(code, e.to_string())
    }
}

/// The stable name of a result (`"ok"`, `"truncated"`, `"buffer_too_short"`,
/// ...): a static NUL-terminated string, never NULL; `"unknown"` for a
/// value no result has.
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn psao_result_name(result: u32) -> *const c_char {
    psao_result::from_u32(result)
        .map_or(c"unknown", psao_result::c_name)
        .as_ptr()
}
