//! The client half: a decoder with its mirror. Frames in
//! (`psao_decoder_receive`), events out, the mirror's state and sequence,
//! its digest, and the instance list.

use psao_codec::{Decoder, Event, Transform};

use crate::boundary::{
    ErrorSlot, Object, OutArray, call, call_on, give, last_error, out_ptr, put, read_in, slice_in,
    take,
};
use crate::result::{Failure, psao_result};
use crate::types::{psao_event, psao_event_kind, psao_instance_info, psao_limits, psao_transform};

/// A decoder and the mirror it keeps: the client's copy of every instance
/// at one sequence number. Made by `psao_decoder_new`, freed by
/// `psao_decoder_free`.
///
/// Thread-safety: a decoder may be used from one thread at a time and may
/// move between threads; two decoders are independent. Every call, the
/// read-only ones included, takes the decoder mutably (it keeps the last
/// error): threads that reconstruct in parallel each need their own
/// decoder, or copy the mirror's arrays out and share those.
#[allow(non_camel_case_types)]
pub struct psao_decoder {
    pub(crate) decoder: Decoder,
    slot: ErrorSlot,
}

impl Object for psao_decoder {
    fn slot(&mut self) -> &mut ErrorSlot {
        &mut self.slot
    }
}

impl psao_decoder {
    /// The instance `id`, or `PSAO_ERROR_NOT_FOUND`.
    pub(crate) fn instance(&self, id: u32) -> Result<&psao_codec::InstanceMirror, Failure> {
        self.decoder.mirror().instance(id).ok_or_else(|| {
            Failure::new(
                psao_result::PSAO_ERROR_NOT_FOUND,
                format!("instance {id} is not in the mirror"),
            )
        })
    }
}

/// The spec's default limits.
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn psao_limits_default() -> psao_limits {
    psao_codec::Limits::default().into()
}

/// Makes a decoder with an empty mirror, waiting for a keyframe.
/// `limits` may be NULL for the defaults. On success `*out` receives the
/// decoder; free it with `psao_decoder_free`.
///
/// # Safety
///
/// `limits` is NULL or points to a `psao_limits`; `out` is valid for a
/// write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_new(
    limits: *const psao_limits,
    out: *mut *mut psao_decoder,
) -> psao_result {
    call(|| {
        let out = out_ptr(out, "out")?;
        let limits = if limits.is_null() {
            psao_codec::Limits::default()
        } else {
            // SAFETY: not NULL, points to a `psao_limits` by the contract.
            unsafe { read_in(limits, "limits") }?.into()
        };
        let decoder = psao_decoder {
            decoder: Decoder::new(limits),
            slot: ErrorSlot::default(),
        };
        // SAFETY: `out` is valid for a write by the contract.
        unsafe { give(out, decoder) };
        Ok(())
    })
}

/// Frees a decoder; NULL is ignored.
///
/// # Safety
///
/// `decoder` is NULL or from `psao_decoder_new`, not freed before, and not
/// in use by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_free(decoder: *mut psao_decoder) {
    // SAFETY: the contract above is `take`'s.
    unsafe { take(decoder) }
}

/// Decodes one frame of `len` bytes and applies it to the mirror, whole or
/// not at all. On success `*event` says what happened; on failure the
/// result is the spec's error class (`PSAO_ERROR_TRUNCATED`, ...), the
/// mirror is unchanged, and `psao_decoder_last_error` gives the details.
/// The next delta after a failure reports `PSAO_EVENT_NEED_KEYFRAME`.
/// Nothing is allocated beyond the decoder's limits.
///
/// # Safety
///
/// `decoder` is a live decoder; `bytes` is valid for reads of `len` bytes
/// (or NULL with `len == 0`) that nothing writes during the call; `event`
/// is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_receive(
    decoder: *mut psao_decoder,
    bytes: *const u8,
    len: usize,
    event: *mut psao_event,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let event = out_ptr(event, "event")?;
        // SAFETY: `bytes` is valid for `len` reads (contract).
        let frame = unsafe { slice_in(bytes, len, "bytes") }?;
        let e = d.decoder.receive(frame)?;
        // SAFETY: `event` is valid for a write (contract).
        unsafe { put(event, event_of(e)) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

fn event_of(e: Event) -> psao_event {
    let mut out = psao_event {
        kind: psao_event_kind::PSAO_EVENT_APPLIED,
        sequence: 0,
        keyframe: 0,
        have_valid: 0,
        have: 0,
        base: 0,
    };
    match e {
        Event::Applied { sequence, keyframe } => {
            out.sequence = sequence;
            out.keyframe = keyframe as u8;
        }
        Event::Stale { sequence, have } => {
            out.kind = psao_event_kind::PSAO_EVENT_STALE;
            out.sequence = sequence;
            out.have = have;
            out.have_valid = 1;
        }
        Event::NeedKeyframe {
            have,
            base,
            sequence,
        } => {
            out.kind = psao_event_kind::PSAO_EVENT_NEED_KEYFRAME;
            out.sequence = sequence;
            out.base = base;
            out.have_valid = have.is_some() as u8;
            out.have = have.unwrap_or(0);
        }
        // A future event this API does not know yet: the safe reading is
        // that the mirror did not move on.
        _ => out.kind = psao_event_kind::PSAO_EVENT_NEED_KEYFRAME,
    }
    out
}

/// The mirror's sequence into `*sequence`; `PSAO_ERROR_NO_STATE` before
/// the first keyframe.
///
/// # Safety
///
/// `decoder` is a live decoder; `sequence` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_sequence(
    decoder: *mut psao_decoder,
    sequence: *mut u32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(sequence, "sequence")?;
        let s = d.decoder.mirror().sequence().ok_or_else(no_state)?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, s) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

fn no_state() -> Failure {
    Failure::new(
        psao_result::PSAO_ERROR_NO_STATE,
        "the mirror has no keyframe yet",
    )
}

/// The mirror digest of spec/wire-format.md 7.5 into `*digest`, to compare
/// with a server's DIGEST; `PSAO_ERROR_NO_STATE` before the first
/// keyframe. It reads the whole mirror (about 1 ms per 10 MB): compute it
/// when a digest is to be checked, not per frame.
///
/// # Safety
///
/// `decoder` is a live decoder; `digest` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_digest(
    decoder: *mut psao_decoder,
    digest: *mut u32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(digest, "digest")?;
        let v = d.decoder.mirror().digest().ok_or_else(no_state)?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, v) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// Bytes the mirror holds in bucket entries and words, into `*bytes`
/// (bounded by the limits' `max_mirror_bytes`).
///
/// # Safety
///
/// `decoder` is a live decoder; `bytes` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_mirror_bytes(
    decoder: *mut psao_decoder,
    bytes: *mut u64,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(bytes, "bytes")?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, d.decoder.mirror().bytes()) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// The ids of the mirror's instances, ascending, into `ids[0..*len]`.
/// `*len` receives the count; with fewer than that in `cap`, nothing is
/// written and the result is `PSAO_ERROR_BUFFER_TOO_SHORT` (call with
/// `cap == 0` to ask for the count).
///
/// # Safety
///
/// `decoder` is a live decoder; `ids` is valid for writes of `cap` ids
/// (NULL with `cap == 0`); `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_instance_ids(
    decoder: *mut psao_decoder,
    ids: *mut u32,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let len = out_ptr(len, "len")?;
        let out = OutArray::new(ids, cap, "ids")?;
        let all: Vec<u32> = d.decoder.mirror().instances().map(|(id, _)| id).collect();
        // SAFETY: `ids` holds `cap` ids and `len` is writable (contract).
        unsafe { out.fill(&all, len, "ids") }
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// What the mirror holds for instance `id`: its definition, transform and
/// array sizes. `PSAO_ERROR_NOT_FOUND` when it is not in the mirror
/// (`PSAO_ERROR_UNKNOWN_INSTANCE` is the frame-level class, for a message
/// that names one).
///
/// # Safety
///
/// `decoder` is a live decoder; `info` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_instance(
    decoder: *mut psao_decoder,
    id: u32,
    info: *mut psao_instance_info,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(info, "info")?;
        let inst = d.instance(id)?;
        let identity = psao_transform {
            sequence: 0,
            matrix: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        };
        let value = psao_instance_info {
            def: inst.def().into(),
            has_transform: inst.transform().is_some() as u8,
            transform: inst.transform().map_or(identity, |&t| t.into()),
            bucket_entries: inst.buckets().len() as u32,
            words: inst.words().len() as u32,
        };
        // SAFETY: valid for a write (contract).
        unsafe { put(out, value) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// Applies a transform that arrived outside a frame (a datagram, say).
/// `*replaced` receives 1 when it replaced the stored one (it was newer),
/// else 0. As in Rust: `PSAO_ERROR_NON_FINITE_TRANSFORM` for NaN or
/// infinity, then `PSAO_ERROR_UNKNOWN_INSTANCE` for an instance not in the
/// mirror.
///
/// # Safety
///
/// `decoder` is a live decoder; `transform` points to a `psao_transform`;
/// `replaced` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_apply_transform(
    decoder: *mut psao_decoder,
    id: u32,
    transform: *const psao_transform,
    replaced: *mut u8,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(replaced, "replaced")?;
        // SAFETY: points to a `psao_transform` (contract).
        let t = unsafe { read_in(transform, "transform") }?;
        let r = d.decoder.mirror_mut().apply_transform(
            id,
            Transform {
                sequence: t.sequence,
                matrix: t.matrix,
            },
        )?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, r as u8) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// The message of the decoder's last failure, NUL-terminated, into
/// `buf`; `*len` receives its length without the NUL (0 after a success).
/// A buffer too short for the message and its NUL gets nothing,
/// `PSAO_ERROR_BUFFER_TOO_SHORT`, and in `*len` the bytes it needs.
///
/// # Safety
///
/// `decoder` is a live decoder; `buf` is valid for writes of `cap` bytes;
/// `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_last_error(
    decoder: *mut psao_decoder,
    buf: *mut std::ffi::c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    // SAFETY: the contract above is `last_error`'s.
    unsafe { last_error(decoder, buf, cap, len) }
}

/// The message of this thread's last failed call that had no object to
/// keep it (a `_new` function, `psao_point_word_fields`,
/// `psao_normal_table`), as `psao_decoder_last_error`. Calls on an object
/// keep theirs in the object.
///
/// Thread-safe (each thread has its own).
///
/// # Safety
///
/// `buf` is valid for writes of `cap` bytes; `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_last_error(
    buf: *mut std::ffi::c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    // SAFETY: the contract above is `thread_last_error`'s.
    unsafe { crate::boundary::thread_last_error(buf, cap, len) }
}

/// The `PsaoInstance` record of instance `id` for a port of the
/// reconstruction shader (docs/c-api.md): 48 32-bit words (192 bytes,
/// std430; floats as their bits) into `out[0..48]`, with the instance's
/// bucket entries at entry `first_bucket` of the engine's bucket buffer
/// and its words at word `first_word` of its word buffer. The inverse
/// transform, its invertibility test and the weight parameters are the
/// ones the CPU reconstruction uses. `PSAO_ERROR_NOT_FOUND` for an
/// instance not in the mirror.
///
/// # Safety
///
/// `decoder` is a live decoder; `out` is valid for writes of 48 words.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_instance_gpu(
    decoder: *mut psao_decoder,
    id: u32,
    first_bucket: u32,
    first_word: u32,
    out: *mut u32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let arr = OutArray::new(out, psao_codec::GPU_RECORD_WORDS, "out")?;
        let record = psao_codec::gpu_instance_record(d.instance(id)?, first_bucket, first_word);
        let mut written = 0usize;
        // SAFETY: `out` holds 48 words (contract).
        unsafe { arr.fill(&record, (&mut written).into(), "out") }
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}
