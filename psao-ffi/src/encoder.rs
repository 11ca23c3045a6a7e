//! The server half, part two: the encoder. A frame is built over several
//! calls: `psao_encoder_begin`, then messages in the order clients apply
//! them (definitions, transforms, tables' changes or snapshots), then
//! `psao_encoder_finish` into the caller's buffer.

use psao_codec::{Compression, EncodedFrame, Encoder, EncoderConfig, FrameBuilder, PausedFrame};

use crate::boundary::{
    ErrorSlot, Object, OutArray, call, call_on, flag, give, last_error, out_ptr, put, read_in, take,
};
use crate::result::{Failure, psao_result};
use crate::table::psao_table;
use crate::types::{
    psao_compression, psao_encoder_config, psao_frame_info, psao_instance_def, psao_transform,
};

/// Writes numbered frames: deltas (sequence + 1) and keyframes (the state
/// at the current sequence). Made by `psao_encoder_new`, freed by
/// `psao_encoder_free`.
///
/// Thread-safety: an encoder may be used from one thread at a time and may
/// move between threads.
#[allow(non_camel_case_types)]
pub struct psao_encoder {
    encoder: Encoder,
    state: FrameState,
    slot: ErrorSlot,
}

/// Where the encoder is between calls.
#[derive(Debug)]
enum FrameState {
    /// No frame begun.
    Idle,
    /// A frame being built.
    Open(PausedFrame),
    /// A finished frame that did not fit the caller's buffer, kept for
    /// the next `psao_encoder_finish`.
    Ready(EncodedFrame),
}

impl Object for psao_encoder {
    fn slot(&mut self) -> &mut ErrorSlot {
        &mut self.slot
    }
}

impl psao_encoder {
    /// Runs `f` on the open frame and puts it aside again.
    fn with_frame(
        &mut self,
        f: impl FnOnce(&mut FrameBuilder<'_>) -> Result<(), Failure>,
    ) -> Result<(), Failure> {
        let paused = match std::mem::replace(&mut self.state, FrameState::Idle) {
            FrameState::Open(p) => p,
            other => {
                let ready = matches!(other, FrameState::Ready(_));
                self.state = other;
                return Err(if ready {
                    frame_open("a finished frame waits for psao_encoder_finish")
                } else {
                    Failure::new(
                        psao_result::PSAO_ERROR_NO_FRAME_OPEN,
                        "no frame is open: call psao_encoder_begin first",
                    )
                });
            }
        };
        let mut builder = self
            .encoder
            .resume(paused)
            .expect("the encoder's own paused frame resumes");
        let r = f(&mut builder);
        self.state = FrameState::Open(builder.pause());
        r
    }
}

fn frame_open(why: &str) -> Failure {
    Failure::new(psao_result::PSAO_ERROR_FRAME_OPEN, why)
}

/// zstd level 3, checksums on, the spec's default limits.
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn psao_encoder_config_default() -> psao_encoder_config {
    let c = EncoderConfig::default();
    psao_encoder_config {
        compression: match c.compression {
            Compression::None => psao_compression::PSAO_COMPRESSION_NONE as u32,
            Compression::Lz4 => psao_compression::PSAO_COMPRESSION_LZ4 as u32,
            _ => psao_compression::PSAO_COMPRESSION_ZSTD as u32,
        },
        zstd_level: c.zstd_level,
        checksum: c.checksum as u8,
        limits: c.limits.into(),
    }
}

/// zstd's fastest level (`ZSTD_minCLevel`).
const ZSTD_MIN_LEVEL: i32 = -(1 << 17);

fn config_of(c: psao_encoder_config) -> Result<EncoderConfig, Failure> {
    let compression = match c.compression {
        0 => Compression::None,
        1 => Compression::Lz4,
        2 => Compression::Zstd,
        v => return Err(Failure::invalid(format!("unknown compression {v}"))),
    };
    if compression == Compression::Zstd && !(ZSTD_MIN_LEVEL..=22).contains(&c.zstd_level) {
        return Err(Failure::invalid(format!(
            "zstd level {} outside zstd's {ZSTD_MIN_LEVEL}..=22",
            c.zstd_level
        )));
    }
    if !compression.available() {
        return Err(psao_codec::EncodeError::CompressionUnavailable(compression).into());
    }
    Ok(EncoderConfig {
        compression,
        zstd_level: c.zstd_level,
        checksum: flag(c.checksum, "config.checksum")?,
        limits: c.limits.into(),
    })
}

/// Makes an encoder whose state is at `start_sequence` (its first delta is
/// `start_sequence + 1`). `config` may be NULL for the defaults. A
/// compression not compiled in is `PSAO_ERROR_COMPRESSION_UNAVAILABLE`.
///
/// # Safety
///
/// `config` is NULL or points to a `psao_encoder_config`; `out` is valid
/// for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_new(
    config: *const psao_encoder_config,
    start_sequence: u32,
    out: *mut *mut psao_encoder,
) -> psao_result {
    call(|| {
        let out = out_ptr(out, "out")?;
        let config = if config.is_null() {
            EncoderConfig::default()
        } else {
            // SAFETY: not NULL, points to a config (contract).
            config_of(unsafe { read_in(config, "config") }?)?
        };
        let encoder = psao_encoder {
            encoder: Encoder::starting_at(config, start_sequence),
            state: FrameState::Idle,
            slot: ErrorSlot::default(),
        };
        // SAFETY: `out` is valid for a write (contract).
        unsafe { give(out, encoder) };
        Ok(())
    })
}

/// Frees an encoder (and any frame it was building); NULL is ignored.
///
/// # Safety
///
/// `encoder` is NULL or from `psao_encoder_new`, not freed before, and not
/// in use by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_free(encoder: *mut psao_encoder) {
    // SAFETY: the contract above is `take`'s.
    unsafe { take(encoder) }
}

/// The sequence of the state encoded so far into `*sequence`.
///
/// # Safety
///
/// `encoder` is a live encoder; `sequence` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_sequence(
    encoder: *mut psao_encoder,
    sequence: *mut u32,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        let out = out_ptr(sequence, "sequence")?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, e.encoder.sequence()) };
        Ok(())
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Changes the configuration for the next frames (compression, level,
/// checksum, receivers' limits); the sequence goes on. Errors as
/// `psao_encoder_new`; `PSAO_ERROR_FRAME_OPEN` while a frame is open.
///
/// # Safety
///
/// `encoder` is a live encoder; `config` points to a `psao_encoder_config`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_set_config(
    encoder: *mut psao_encoder,
    config: *const psao_encoder_config,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        // SAFETY: points to a config (contract).
        let config = config_of(unsafe { read_in(config, "config") }?)?;
        if !matches!(e.state, FrameState::Idle) {
            return Err(frame_open("finish or abort the open frame first"));
        }
        e.encoder.set_config(config);
        Ok(())
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Begins a frame: a delta (`keyframe == 0`, sequence + 1) or a keyframe
/// (`keyframe == 1`, the state at the current sequence: add a snapshot of
/// every table). `PSAO_ERROR_FRAME_OPEN` while another is open or waits to
/// be collected.
///
/// # Safety
///
/// `encoder` is a live encoder.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_begin(
    encoder: *mut psao_encoder,
    keyframe: u8,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        let keyframe = flag(keyframe, "keyframe")?;
        if !matches!(e.state, FrameState::Idle) {
            return Err(frame_open(
                "a frame is open or waits for psao_encoder_finish; finish or abort it",
            ));
        }
        let builder = if keyframe {
            e.encoder.keyframe()
        } else {
            e.encoder.delta()
        };
        e.state = FrameState::Open(builder.pause());
        Ok(())
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Drops the open frame (or a finished one not collected), so the next
/// `psao_encoder_begin` can start. A delta that already held messages
/// takes its sequence number (as one finished and not collected has): the
/// table changes it took are lost to clients, who see a gap and ask for a
/// keyframe instead of silently diverging.
///
/// # Safety
///
/// `encoder` is a live encoder.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_abort(encoder: *mut psao_encoder) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        if let FrameState::Open(paused) = std::mem::replace(&mut e.state, FrameState::Idle) {
            e.encoder.abandon(paused);
        }
        Ok(())
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Adds a DefineInstance (a client clears the instance and takes the new
/// definition). `PSAO_ERROR_INVALID_DEFINITION` for a definition that
/// breaks a rule of the spec.
///
/// # Safety
///
/// `encoder` is a live encoder; `def` points to a `psao_instance_def`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_define_instance(
    encoder: *mut psao_encoder,
    id: u32,
    def: *const psao_instance_def,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        // SAFETY: points to a `psao_instance_def` (contract).
        let def = unsafe { read_in(def, "def") }?.to_def()?;
        e.with_frame(|b| Ok(b.define_instance(id, &def)?))
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Adds a RemoveInstance.
///
/// # Safety
///
/// `encoder` is a live encoder.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_remove_instance(
    encoder: *mut psao_encoder,
    id: u32,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        e.with_frame(|b| {
            b.remove_instance(id);
            Ok(())
        })
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Adds a SetTransform: instance `id`'s local-to-world transform.
/// `PSAO_ERROR_NON_FINITE_TRANSFORM` for NaN or infinity (clients would
/// reject the frame).
///
/// # Safety
///
/// `encoder` is a live encoder; `transform` points to a `psao_transform`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_transform(
    encoder: *mut psao_encoder,
    id: u32,
    transform: *const psao_transform,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        // SAFETY: points to a `psao_transform` (contract).
        let t = unsafe { read_in(transform, "transform") }?;
        if !t.matrix.iter().all(|m| m.is_finite()) {
            return Err(psao_codec::MessageError::NonFiniteTransform.into());
        }
        e.with_frame(|b| {
            b.transform(id, t.sequence, &t.matrix);
            Ok(())
        })
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Checks and borrows a table argument.
///
/// # Safety
///
/// `table` is NULL or a live table not in use by another thread.
unsafe fn table_arg<'a>(table: *mut psao_table) -> Result<&'a mut psao_table, Failure> {
    if table.is_null() {
        return Err(Failure::null("table"));
    }
    // SAFETY: not NULL, live, and used by this thread only (contract); it
    // is a different object from the encoder, so the two unique
    // references do not alias.
    Ok(unsafe { &mut *table })
}

/// Adds everything that changed in `table` since its changes were last
/// taken (by this call or `psao_table_discard_pending`), and takes them.
/// For deltas only: in a keyframe it is `PSAO_ERROR_INVALID_ARGUMENT`
/// (clients that already hold the stream would never get those changes;
/// a keyframe takes `psao_encoder_snapshot`).
///
/// # Safety
///
/// `encoder` is a live encoder; `table` is a live table; neither is in use
/// by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_changes(
    encoder: *mut psao_encoder,
    table: *mut psao_table,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        // SAFETY: `table` is live and used by this thread only.
        let t = unsafe { table_arg(table) }?;
        if matches!(&e.state, FrameState::Open(p) if p.is_keyframe()) {
            return Err(Failure::invalid(
                "psao_encoder_changes in a keyframe: changes go in deltas, a keyframe takes snapshots",
            ));
        }
        e.with_frame(|b| {
            b.changes(&mut t.table);
            Ok(())
        })
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Adds the whole state of `table` (its definition, occupied buckets and
/// cells), for a keyframe. `PSAO_ERROR_PENDING_CHANGES` when the table has
/// changes not yet sent in a delta (the keyframe would not match its
/// sequence).
///
/// # Safety
///
/// `encoder` is a live encoder; `table` is a live table; neither is in use
/// by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_snapshot(
    encoder: *mut psao_encoder,
    table: *mut psao_table,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        // SAFETY: `table` is live and used by this thread only.
        let t = unsafe { table_arg(table) }?;
        e.with_frame(|b| Ok(b.snapshot(&t.table)?))
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

/// Finishes the open frame and copies it into `out[0..*len]`; `*info`
/// (may be NULL) says what it holds. A delta with no message is no frame:
/// `*len` is 0 and the sequence does not advance. When the frame does not
/// fit in `cap` bytes, nothing is written, `*len` receives its size, the
/// result is `PSAO_ERROR_BUFFER_TOO_SHORT`, and the frame is kept: call
/// again with a larger buffer. A frame beyond the receivers' limits is
/// `PSAO_ERROR_RECEIVER_LIMIT`; for a delta its sequence is skipped, so
/// clients see a gap and ask for a keyframe.
///
/// # Safety
///
/// `encoder` is a live encoder; `out` is valid for writes of `cap` bytes
/// (NULL with `cap == 0`); `len` is valid for a write; `info` is NULL or
/// valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_finish(
    encoder: *mut psao_encoder,
    out: *mut u8,
    cap: usize,
    len: *mut usize,
    info: *mut psao_frame_info,
) -> psao_result {
    let body = |e: &mut psao_encoder| -> Result<(), Failure> {
        let len = out_ptr(len, "len")?;
        let buf = OutArray::new(out, cap, "out")?;
        let frame = match std::mem::replace(&mut e.state, FrameState::Idle) {
            FrameState::Idle => {
                return Err(Failure::new(
                    psao_result::PSAO_ERROR_NO_FRAME_OPEN,
                    "no frame is open: call psao_encoder_begin first",
                ));
            }
            FrameState::Ready(frame) => Some(frame),
            FrameState::Open(paused) => {
                let builder = e
                    .encoder
                    .resume(paused)
                    .expect("the encoder's own paused frame resumes");
                builder.finish()?
            }
        };
        let sequence = e.encoder.sequence();
        let Some(frame) = frame else {
            // SAFETY: `len` is valid for a write (contract).
            unsafe { put(len, 0) };
            // SAFETY: `info` is NULL or writable (contract).
            unsafe { write_info(info, empty_info(sequence)) };
            return Ok(());
        };
        // SAFETY: `out` holds `cap` bytes, `len` is writable (contract).
        if let Err(f) = unsafe { buf.fill(&frame.bytes, len, "out") } {
            e.state = FrameState::Ready(frame);
            return Err(f);
        }
        // SAFETY: `info` is NULL or writable (contract).
        unsafe {
            write_info(
                info,
                psao_frame_info {
                    sequence: frame.sequence,
                    keyframe: frame.keyframe as u8,
                    bytes: frame.stats.frame_bytes,
                    messages: frame.stats.messages,
                    points: frame.stats.points,
                    payload_bytes: frame.stats.payload_bytes,
                },
            )
        };
        Ok(())
    };
    // SAFETY: `encoder` is live and used by this thread only (contract).
    unsafe { call_on(encoder, body) }
}

fn empty_info(sequence: u32) -> psao_frame_info {
    psao_frame_info {
        sequence,
        keyframe: 0,
        bytes: 0,
        messages: 0,
        points: 0,
        payload_bytes: 0,
    }
}

/// # Safety
///
/// `info` is NULL or valid for a write.
unsafe fn write_info(info: *mut psao_frame_info, value: psao_frame_info) {
    if let Some(out) = std::ptr::NonNull::new(info) {
        // SAFETY: not NULL, valid for a write by `psao_encoder_finish`'s
        // contract.
        unsafe { put(out, value) };
    }
}

/// The message of the encoder's last failure (as
/// `psao_decoder_last_error`).
///
/// # Safety
///
/// `encoder` is a live encoder; `buf` is valid for writes of `cap` bytes;
/// `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_encoder_last_error(
    encoder: *mut psao_encoder,
    buf: *mut std::ffi::c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    // SAFETY: the contract above is `last_error`'s.
    unsafe { last_error(encoder, buf, cap, len) }
}
