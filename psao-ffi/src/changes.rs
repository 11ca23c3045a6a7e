//! The mirror's changed ranges and copies of its arrays into the engine's
//! own buffers (for GPU upload): after each applied frame, read the
//! changes, copy those ranges, then clear the changes.

use psao_codec::{Change, PointWord};

use crate::boundary::{OutArray, call, call_on, copy_range, out_ptr, put};
use crate::decoder::psao_decoder;
use crate::result::{Failure, psao_result};
use crate::types::{psao_bucket_entry, psao_change, psao_change_kind, psao_point_fields};

/// The ranges changed since the last `psao_decoder_clear_changes`, in the
/// order they were written, into `changes[0..*len]`. `*all` receives 1
/// when everything may have changed (a keyframe, or too many ranges to
/// list): upload every instance then. With fewer than `*len` in `cap`,
/// nothing but `*len` is written and the result is
/// `PSAO_ERROR_BUFFER_TOO_SHORT`. After a rejected frame the list may
/// over-report, never under-report.
///
/// # Safety
///
/// `decoder` is a live decoder; `changes` is valid for writes of `cap`
/// entries (NULL with `cap == 0`); `len` and `all` are valid for writes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_changes(
    decoder: *mut psao_decoder,
    changes: *mut psao_change,
    cap: usize,
    len: *mut usize,
    all: *mut u8,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let len = out_ptr(len, "len")?;
        let all = out_ptr(all, "all")?;
        let out = OutArray::new(changes, cap, "changes")?;
        let c = d.decoder.mirror().changes();
        let n = c.items.iter().filter(|c| change_of(c).is_some()).count();
        let items = c.items.iter().filter_map(change_of);
        // SAFETY: `changes` holds `cap` entries, `len` is writable.
        unsafe { out.fill_iter(n, items, len, "changes") }?;
        // SAFETY: `all` is valid for a write (contract).
        unsafe { put(all, c.all as u8) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

fn change_of(c: &Change) -> Option<psao_change> {
    use psao_change_kind::*;
    let (kind, instance, start, end) = match c {
        Change::Defined(i) => (PSAO_CHANGE_DEFINED, *i, 0, 0),
        Change::Removed(i) => (PSAO_CHANGE_REMOVED, *i, 0, 0),
        Change::Transform(i) => (PSAO_CHANGE_TRANSFORM, *i, 0, 0),
        Change::Buckets(i, r) => (PSAO_CHANGE_BUCKETS, *i, r.start, r.end),
        Change::Words(i, r) => (PSAO_CHANGE_WORDS, *i, r.start, r.end),
        // A kind this API does not know yet: an instance-wide kind would
        // be listed above; the codec sets `all` for anything it cannot
        // list, so skipping cannot under-report.
        _ => return None,
    };
    Some(psao_change {
        kind,
        instance,
        start,
        end,
    })
}

/// Forgets the recorded changes (after the engine uploaded them).
///
/// # Safety
///
/// `decoder` is a live decoder.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_clear_changes(decoder: *mut psao_decoder) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        d.decoder.mirror_mut().clear_changes();
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// Copies point words `[first, first + count)` of instance `id` (the
/// mirror's layout: `cell * cell_capacity + slot`, 0 for an empty slot)
/// into `words`. `PSAO_ERROR_OUT_OF_RANGE` beyond the instance's words,
/// `PSAO_ERROR_NOT_FOUND` for an instance not in the mirror.
///
/// # Safety
///
/// `decoder` is a live decoder; `words` is valid for writes of `count`
/// words (NULL with `count == 0`) and is not memory of a psao object.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_copy_words(
    decoder: *mut psao_decoder,
    id: u32,
    first: u32,
    count: usize,
    words: *mut u32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = OutArray::new(words, count, "words")?;
        let all = d.instance(id)?.words();
        // SAFETY: `words` holds `count` words (contract).
        unsafe { copy_range(all, first, out, "words", |&w| w) }
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// Copies bucket entries `[first, first + count)` of instance `id` (entry
/// `bucket * bucket_capacity + i`; empty entries are
/// `{0xFFFFFFFF, 0xFFFFFFFF}`) into `entries`. Errors as
/// `psao_decoder_copy_words`.
///
/// # Safety
///
/// `decoder` is a live decoder; `entries` is valid for writes of `count`
/// entries (NULL with `count == 0`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_copy_buckets(
    decoder: *mut psao_decoder,
    id: u32,
    first: u32,
    count: usize,
    entries: *mut psao_bucket_entry,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = OutArray::new(entries, count, "entries")?;
        let all = d.instance(id)?.buckets();
        // SAFETY: `entries` holds `count` entries (contract).
        unsafe { copy_range(all, first, out, "bucket entries", |e| e.into()) }
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// The fields of point word `word` (quantized position, normal code, AO
/// steps) into `*fields`. Any 32-bit value has fields; whether it is a
/// valid word is the decoder's business.
///
/// # Safety
///
/// `fields` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_point_word_fields(
    word: u32,
    fields: *mut psao_point_fields,
) -> psao_result {
    call(|| {
        let out = out_ptr(fields, "fields")?;
        let f = PointWord(word).fields();
        let value = psao_point_fields {
            position: f.position.to_array(),
            normal: f.normal,
            ao: f.ao,
        };
        // SAFETY: valid for a write (contract).
        unsafe { put(out, value) };
        Ok(())
    })
}

/// The 256 decoded normals of the point words' normal codes
/// (spec/wire-format.md 6) as `x, y, z, 0` per code, into `out[0..1024]`: the
/// table a shader port of the reconstruction binds (`psao_normals` of
/// psao-gpu's `reconstruct.wgsl`). `*len` receives 1024; a shorter `out`
/// gets nothing and `PSAO_ERROR_BUFFER_TOO_SHORT`.
///
/// # Safety
///
/// `out` is valid for writes of `cap` floats; `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_normal_table(
    out: *mut f32,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    call(|| {
        let len = out_ptr(len, "len")?;
        let out = OutArray::new(out, cap, "out")?;
        let table: Vec<f32> = psao_codec::normal_table()
            .iter()
            .flat_map(|n| [n.x, n.y, n.z, 0.0])
            .collect();
        // SAFETY: `out` holds `cap` floats, `len` is writable (contract).
        unsafe { out.fill(&table, len, "out") }
    })
}
