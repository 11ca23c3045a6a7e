//! The server half, part one: the authoritative hash grid of one instance.
//! A server with its own ray tracer sets each point's position, normal and
//! AO here; the encoder sends what changed.

use psao_codec::{DropReason, GridTable, Limits, Placement, Thresholds};

use crate::boundary::{
    ErrorSlot, Object, OutArray, call, call_on, copy_range, give, last_error, out_ptr, put,
    read_in, take,
};
use crate::result::{Failure, psao_result};
use crate::types::{
    psao_bucket_entry, psao_drop_reason, psao_instance_def, psao_limits, psao_placement,
    psao_placement_kind, psao_table_stats, psao_thresholds,
};

/// The authoritative hash grid of one instance (points by dense id below
/// `max_points`). Made by `psao_table_new`, freed by `psao_table_free`.
///
/// Thread-safety: a table may be used from one thread at a time and may
/// move between threads (a server may trace on many threads and set the
/// points from one).
#[allow(non_camel_case_types)]
pub struct psao_table {
    pub(crate) table: GridTable,
    slot: ErrorSlot,
}

impl Object for psao_table {
    fn slot(&mut self) -> &mut ErrorSlot {
        &mut self.slot
    }
}

/// The paper's thresholds: 3 position quanta, normal cosine 0.6, 8 AO steps.
///
/// Thread-safe.
#[unsafe(no_mangle)]
pub extern "C" fn psao_thresholds_default() -> psao_thresholds {
    Thresholds::default().into()
}

/// Makes an empty table for instance `id`. Its memory is fixed by `def`
/// (bucket entries and words, as a client's mirror of it, plus bookkeeping)
/// and by 8 bytes per point id below `max_points`. `limits` (NULL for the
/// defaults) are the receivers': a definition whose table size, cell pool
/// or mirror bytes exceed them on its own is refused with the decoder's
/// code (`PSAO_ERROR_RESOURCE_LIMIT`; the count of instances and their
/// bytes together are the server's to keep within `max_instances` and
/// `max_mirror_bytes`). An invalid definition is
/// `PSAO_ERROR_INVALID_DEFINITION`, as is a cell pool of 2^32 - 6 cells or
/// more (the table marks absent points with the top indices).
///
/// # Safety
///
/// `def` points to a `psao_instance_def`; `limits` is NULL or points to a
/// `psao_limits`; `out` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_new(
    id: u32,
    def: *const psao_instance_def,
    max_points: u32,
    limits: *const psao_limits,
    out: *mut *mut psao_table,
) -> psao_result {
    call(|| {
        let out = out_ptr(out, "out")?;
        // SAFETY: points to a `psao_instance_def` (contract).
        let def = unsafe { read_in(def, "def") }?.to_def()?;
        let limits: Limits = if limits.is_null() {
            Limits::default()
        } else {
            // SAFETY: not NULL, points to a `psao_limits` (contract).
            unsafe { read_in(limits, "limits") }?.into()
        };
        def.validate().map_err(psao_codec::MessageError::Def)?;
        let resource = |needed: u64, limit: u64| {
            Err(Failure::new(
                psao_result::PSAO_ERROR_RESOURCE_LIMIT,
                format!(
                    "instance needs {needed} bytes / cells / buckets above the receiver limit {limit}"
                ),
            ))
        };
        if def.table_log2 > limits.max_table_log2 {
            return resource(def.table_size() as u64, 1u64 << limits.max_table_log2);
        }
        if def.cell_pool > limits.max_cell_pool {
            return resource(def.cell_pool as u64, limits.max_cell_pool as u64);
        }
        if def.mirror_bytes() as u64 > limits.max_mirror_bytes {
            return resource(def.mirror_bytes() as u64, limits.max_mirror_bytes);
        }
        let table = GridTable::new(id, def, max_points)?;
        // SAFETY: `out` is valid for a write (contract).
        unsafe {
            give(
                out,
                psao_table {
                    table,
                    slot: ErrorSlot::default(),
                },
            )
        };
        Ok(())
    })
}

/// Frees a table; NULL is ignored.
///
/// # Safety
///
/// `table` is NULL or from `psao_table_new`, not freed before, and not in
/// use by another thread.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_free(table: *mut psao_table) {
    // SAFETY: the contract above is `take`'s.
    unsafe { take(table) }
}

fn placement_of(p: Placement) -> psao_placement {
    use psao_drop_reason::*;
    let mut out = psao_placement {
        kind: psao_placement_kind::PSAO_PLACEMENT_ABSENT,
        cell: u32::MAX,
        slot: 0,
        drop_reason: PSAO_DROP_NONE,
    };
    match p {
        Placement::Absent => {}
        Placement::Stored { cell, slot } => {
            out.kind = psao_placement_kind::PSAO_PLACEMENT_STORED;
            out.cell = cell;
            out.slot = slot;
        }
        Placement::Dropped(r) => {
            out.kind = psao_placement_kind::PSAO_PLACEMENT_DROPPED;
            out.drop_reason = match r {
                DropReason::OutOfGrid => PSAO_DROP_OUT_OF_GRID,
                DropReason::BucketFull => PSAO_DROP_BUCKET_FULL,
                DropReason::CellFull => PSAO_DROP_CELL_FULL,
                _ => PSAO_DROP_POOL_EXHAUSTED,
            };
        }
    }
    out
}

/// Sets point `id` (inserting, moving or updating it): `position` in the
/// instance's grid space, `normal` of any length, `ao` in `[0, 1]`.
/// `*placement` (may be NULL) receives where it ended up; a dropped point
/// is not an error (the table's stats count it). `PSAO_ERROR_POINT_ID`
/// for `id >= max_points`.
///
/// # Safety
///
/// `table` is a live table; `position` and `normal` point to 3 floats (x, y, z);
/// `placement` is NULL or valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_set_point(
    table: *mut psao_table,
    id: u32,
    position: *const f32,
    normal: *const f32,
    ao: f32,
    placement: *mut psao_placement,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        // SAFETY: point to 3 floats (x, y, z) each (contract).
        let p = unsafe { crate::boundary::read_vec3(position, "position") }?;
        // SAFETY: as above.
        let n = unsafe { crate::boundary::read_vec3(normal, "normal") }?;
        let at = t.table.set_point(id, p, n, ao)?;
        if let Some(out) = std::ptr::NonNull::new(placement) {
            // SAFETY: not NULL, valid for a write (contract).
            unsafe { put(out, placement_of(at)) };
        }
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Sets point `id` only if it differs from what clients hold by more than
/// `thresholds` (NULL for the defaults), or its AO became fully open (255)
/// while clients hold less, or it moved to another cell, or is not
/// stored. `*sent` receives 1 when it was set, else 0 (a point set
/// but dropped, see `psao_table_placement`, is not sent).
///
/// # Safety
///
/// `table` is a live table; `position` and `normal` point to 3 floats (x, y, z);
/// `thresholds` is NULL or points to a `psao_thresholds`; `sent` is valid
/// for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_update_point(
    table: *mut psao_table,
    id: u32,
    position: *const f32,
    normal: *const f32,
    ao: f32,
    thresholds: *const psao_thresholds,
    sent: *mut u8,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = out_ptr(sent, "sent")?;
        // SAFETY: point to 3 floats (x, y, z) each (contract).
        let p = unsafe { crate::boundary::read_vec3(position, "position") }?;
        // SAFETY: as above.
        let n = unsafe { crate::boundary::read_vec3(normal, "normal") }?;
        let th: Thresholds = if thresholds.is_null() {
            Thresholds::default()
        } else {
            // SAFETY: not NULL, points to a `psao_thresholds` (contract).
            unsafe { read_in(thresholds, "thresholds") }?.into()
        };
        let s = t.table.update_point(id, p, n, ao, &th)?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, s as u8) };
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Where point `id` stands now (absent, stored in a cell and slot, or
/// dropped and why) into `*placement`.
///
/// # Safety
///
/// `table` is a live table; `placement` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_placement(
    table: *mut psao_table,
    id: u32,
    placement: *mut psao_placement,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = out_ptr(placement, "placement")?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, placement_of(t.table.placement(id))) };
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Removes point `id`; `*was_stored` (may be NULL) receives 1 when it was
/// stored.
///
/// # Safety
///
/// `table` is a live table; `was_stored` is NULL or valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_remove_point(
    table: *mut psao_table,
    id: u32,
    was_stored: *mut u8,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let stored = t.table.remove_point(id);
        if let Some(out) = std::ptr::NonNull::new(was_stored) {
            // SAFETY: not NULL, valid for a write (contract).
            unsafe { put(out, stored as u8) };
        }
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// The table's counters into `*stats`.
///
/// # Safety
///
/// `table` is a live table; `stats` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_get_stats(
    table: *mut psao_table,
    stats: *mut psao_table_stats,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = out_ptr(stats, "stats")?;
        let s = t.table.stats();
        let value = psao_table_stats {
            stored: s.stored,
            cells: s.cells,
            dropped: s.dropped,
            out_of_grid: s.out_of_grid,
            bucket_overflow: s.bucket_overflow,
            cell_overflow: s.cell_overflow,
            pool_exhausted: s.pool_exhausted,
        };
        // SAFETY: valid for a write (contract).
        unsafe { put(out, value) };
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// `*pending` receives 1 when the table has changes not yet written into
/// a delta (`psao_encoder_changes`), else 0.
///
/// # Safety
///
/// `table` is a live table; `pending` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_has_pending(
    table: *mut psao_table,
    pending: *mut u8,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = out_ptr(pending, "pending")?;
        // SAFETY: valid for a write (contract).
        unsafe { put(out, t.table.has_pending() as u8) };
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Forgets the table's pending changes without sending them (a server
/// that fills its tables before any client joins, and then sends
/// keyframes only).
///
/// # Safety
///
/// `table` is a live table.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_discard_pending(table: *mut psao_table) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        t.table.take_dirty();
        Ok(())
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Copies the table's point words `[first, first + count)` (the mirror's
/// layout) into `words`, for checks against a client. Errors as
/// `psao_decoder_copy_words`.
///
/// # Safety
///
/// `table` is a live table; `words` is valid for writes of `count` words
/// (NULL with `count == 0`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_copy_words(
    table: *mut psao_table,
    first: u32,
    count: usize,
    words: *mut u32,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = OutArray::new(words, count, "words")?;
        // SAFETY: `words` holds `count` words (contract).
        unsafe { copy_range(t.table.words(), first, out, "words", |&w| w) }
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// Copies the table's bucket entries `[first, first + count)` into
/// `entries`. Errors as `psao_decoder_copy_words`.
///
/// # Safety
///
/// `table` is a live table; `entries` is valid for writes of `count`
/// entries (NULL with `count == 0`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_copy_buckets(
    table: *mut psao_table,
    first: u32,
    count: usize,
    entries: *mut psao_bucket_entry,
) -> psao_result {
    let body = |t: &mut psao_table| -> Result<(), Failure> {
        let out = OutArray::new(entries, count, "entries")?;
        let all = t.table.buckets();
        // SAFETY: `entries` holds `count` entries (contract).
        unsafe { copy_range(all, first, out, "bucket entries", |e| e.into()) }
    };
    // SAFETY: `table` is live and used by this thread only (contract).
    unsafe { call_on(table, body) }
}

/// The message of the table's last failure (as `psao_decoder_last_error`).
///
/// # Safety
///
/// `table` is a live table; `buf` is valid for writes of `cap` bytes;
/// `len` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_table_last_error(
    table: *mut psao_table,
    buf: *mut std::ffi::c_char,
    cap: usize,
    len: *mut usize,
) -> psao_result {
    // SAFETY: the contract above is `last_error`'s.
    unsafe { last_error(table, buf, cap, len) }
}
