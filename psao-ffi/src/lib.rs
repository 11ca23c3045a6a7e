//! # psao-ffi
//!
//! The C API of the PSAO codec (`include/psao.h`), for C and C++ engines
//! and streaming servers: both halves of psao-codec's sans-IO core.
//!
//! - Client: [`psao_decoder`] receives frames (`psao_decoder_receive`),
//!   keeps the mirror, reports what a renderer must do
//!   ([`psao_event`]), lists the changed ranges ([`psao_change`]) and
//!   copies them into the engine's buffers, gives the mirror digest of
//!   spec/wire-format.md 7.5, and reconstructs AO on the CPU.
//! - Server: [`psao_table`] is one instance's authoritative hash grid (set
//!   or update points with thresholds); [`psao_encoder`] writes deltas and
//!   keyframes with the spec's compressions.
//!
//! The conventions are rustls-ffi's: opaque objects made by `_new` and
//! freed once by `_free`; every fallible call returns a [`psao_result`]
//! (decode errors are the spec's error classes, one code each, named by
//! `psao_result_name`); the failure's message is kept by the object
//! (`psao_*_last_error`); outputs go to caller-owned memory, arrays with
//! their capacity and a length out, and are written only on success (a
//! short array gets `PSAO_ERROR_BUFFER_TOO_SHORT` and the length it
//! needs); every pointer is checked; a panic is caught at the boundary
//! and poisons its object. Nothing allocates beyond the limits a caller
//! configured. Objects are used from one thread at a time and may move
//! between threads. Inputs must not be written by anyone during a call,
//! and outputs must not point into psao's own objects.
//!
//! This crate is the one place in the workspace with `unsafe` code: each
//! entry point states its contract under `# Safety`, and each `unsafe`
//! block says why that contract makes it sound.
#![allow(unsafe_code)]
#![deny(clippy::undocumented_unsafe_blocks)]

mod boundary;
mod changes;
mod decoder;
mod encoder;
mod reconstruct;
mod result;
mod table;
mod types;

pub use changes::{
    psao_decoder_changes, psao_decoder_clear_changes, psao_decoder_copy_buckets,
    psao_decoder_copy_words, psao_normal_table, psao_point_word_fields,
};
pub use decoder::{
    psao_decoder, psao_decoder_apply_transform, psao_decoder_digest, psao_decoder_free,
    psao_decoder_instance, psao_decoder_instance_gpu, psao_decoder_instance_ids,
    psao_decoder_last_error, psao_decoder_mirror_bytes, psao_decoder_new, psao_decoder_receive,
    psao_decoder_sequence, psao_last_error, psao_limits_default,
};
pub use encoder::{
    psao_encoder, psao_encoder_abort, psao_encoder_begin, psao_encoder_changes,
    psao_encoder_config_default, psao_encoder_define_instance, psao_encoder_finish,
    psao_encoder_free, psao_encoder_last_error, psao_encoder_new, psao_encoder_remove_instance,
    psao_encoder_sequence, psao_encoder_set_config, psao_encoder_snapshot, psao_encoder_transform,
};
pub use reconstruct::{
    psao_decoder_reconstruct, psao_decoder_reconstruct_many, psao_decoder_reconstruct_world,
    psao_decoder_reconstruct_world_many,
};
pub use result::{psao_result, psao_result_name};
pub use table::{
    psao_table, psao_table_copy_buckets, psao_table_copy_words, psao_table_discard_pending,
    psao_table_free, psao_table_get_stats, psao_table_has_pending, psao_table_last_error,
    psao_table_new, psao_table_placement, psao_table_remove_point, psao_table_set_point,
    psao_table_update_point, psao_thresholds_default,
};
pub use types::{
    psao_bucket_entry, psao_change, psao_change_kind, psao_compression, psao_drop_reason,
    psao_encoder_config, psao_event, psao_event_kind, psao_frame_info, psao_instance_def,
    psao_instance_info, psao_limits, psao_placement, psao_placement_kind, psao_point_fields,
    psao_table_stats, psao_thresholds, psao_transform,
};

/// The wire-format version this library speaks (header byte 4).
pub const PSAO_WIRE_VERSION: u8 = 1;

/// The library's version, a static NUL-terminated string.
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn psao_version() -> *const std::ffi::c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// The decoder, tables and encoder are plain data owned by one object each:
/// they may move between threads (what "used from one thread at a time"
/// relies on).
const _: () = {
    const fn assert_send<T: Send>() {}
    assert_send::<psao_decoder>();
    assert_send::<psao_table>();
    assert_send::<psao_encoder>();
};
