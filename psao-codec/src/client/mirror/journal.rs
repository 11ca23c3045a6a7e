//! Applying a delta whole or not at all: the journal of what each write
//! overwrote (or, for XOR and AO deltas, the message to invert), its budget
//! (spec 9), the per-frame state, and the rollback.

use std::ops::Range;

use super::changes::{Change, Changes, push_change};
use super::{InstanceMirror, Mirror, Transform};
use crate::error::MessageError;
use crate::grid::{BucketEntry, InstanceDef};
use crate::limits::Limits;
use crate::wire::message::{Message, Reader};
use crate::wire::point::PointWord;

/// One journal entry: what a write overwrote. Kept small (the instance is
/// boxed) because one is pushed per touched cell and bucket.
#[derive(Clone)]
pub(super) enum Undo {
    Instance(u32, Option<Box<InstanceMirror>>),
    Transform(u32, Option<Box<Transform>>),
    Words {
        instance: u32,
        start: u32,
        len: u8,
        saved: u32,
    },
    Entries {
        instance: u32,
        start: u32,
        len: u8,
        saved: u32,
    },
    /// The first `applied` cells of the `CellsXor` or `CellsAo` message at
    /// payload `offset`: undone by applying the message's inverse (XOR is
    /// its own inverse; AO deltas are subtracted), so nothing is copied.
    Inverse {
        instance: u32,
        offset: u32,
        applied: u32,
    },
}

/// What the frame being applied has done so far.
#[derive(Clone, Default)]
pub(super) struct FrameState {
    /// A keyframe: the whole previous state is kept aside, nothing is
    /// journaled.
    pub(super) keyframe: bool,
    /// Instances defined, redefined or removed by this frame: their
    /// pre-frame version is already saved (or did not exist), so later
    /// writes to them need no journal.
    pub(super) fresh: std::collections::BTreeSet<u32>,
    /// Bytes this frame may still journal, and still allocate in
    /// definitions (each starts at `max_mirror_bytes`).
    pub(super) journal_budget: u64,
    pub(super) alloc_budget: u64,
}

impl FrameState {
    pub(super) fn start(keyframe: bool, limits: &Limits) -> FrameState {
        FrameState {
            keyframe,
            fresh: Default::default(),
            journal_budget: limits.max_mirror_bytes,
            alloc_budget: limits.max_mirror_bytes,
        }
    }

    /// Whether writes to `instance` must be journaled.
    pub(super) fn journals(&self, instance: u32) -> bool {
        !self.keyframe && !self.fresh.contains(&instance)
    }
}

/// Largest journal buffers kept between frames; larger ones are shrunk.
const KEEP_JOURNAL_BYTES: usize = 4 << 20;

impl Mirror {
    pub(super) fn rollback(&mut self, payload: &[u8]) {
        while let Some(u) = self.journal.pop() {
            match u {
                Undo::Inverse {
                    instance,
                    offset,
                    applied,
                } => {
                    if let Some(m) = self.instances.get_mut(&instance) {
                        undo_cells(m, payload, offset as usize, applied as usize);
                    }
                }
                Undo::Instance(id, old) => {
                    match old {
                        Some(m) => self.instances.insert(id, *m),
                        None => self.instances.remove(&id),
                    };
                }
                Undo::Transform(id, old) => {
                    if let Some(m) = self.instances.get_mut(&id) {
                        m.transform = old.map(|t| *t);
                    }
                }
                Undo::Words {
                    instance,
                    start,
                    len,
                    saved,
                } => {
                    if let Some(m) = self.instances.get_mut(&instance) {
                        let (s, o) = (start as usize, saved as usize);
                        m.words[s..s + len as usize]
                            .copy_from_slice(&self.saved_words[o..o + len as usize]);
                    }
                }
                Undo::Entries {
                    instance,
                    start,
                    len,
                    saved,
                } => {
                    if let Some(m) = self.instances.get_mut(&instance) {
                        let (s, o) = (start as usize, saved as usize);
                        m.buckets[s..s + len as usize]
                            .copy_from_slice(&self.saved_entries[o..o + len as usize]);
                    }
                }
            }
        }
        self.clear_journal();
    }

    pub(super) fn clear_journal(&mut self) {
        self.journal.clear();
        self.saved_words.clear();
        self.saved_entries.clear();
        if self.saved_words.capacity() * 4 > KEEP_JOURNAL_BYTES {
            self.saved_words.shrink_to(KEEP_JOURNAL_BYTES / 4);
        }
        if self.saved_entries.capacity() * 8 > KEEP_JOURNAL_BYTES {
            self.saved_entries.shrink_to(KEEP_JOURNAL_BYTES / 8);
        }
        if self.journal.capacity() * std::mem::size_of::<Undo>() > KEEP_JOURNAL_BYTES {
            self.journal
                .shrink_to(KEEP_JOURNAL_BYTES / std::mem::size_of::<Undo>());
        }
        self.frame.fresh.clear();
    }
}

/// Undoes the first `applied` cells of the `CellsXor` or `CellsAo` message
/// at `offset` of `payload` (already checked when it applied).
fn undo_cells(m: &mut InstanceMirror, payload: &[u8], offset: usize, applied: usize) {
    let Some(Ok(message)) = payload.get(offset..).map(|p| Reader::new(p).message()) else {
        return;
    };
    let cap = m.def.cell_capacity as usize;
    let (msg, xor) = match message {
        Message::CellsXor(msg) => (msg, true),
        Message::CellsAo(msg) => (msg, false),
        _ => return,
    };
    let words = msg.words();
    let mut next = 0usize;
    for (cell, &mask) in msg.cells.iter().zip(msg.per_cell).take(applied) {
        let base = cell as usize * cap;
        for slot in 0..cap {
            if mask & (1 << slot) == 0 {
                continue;
            }
            let w = &mut m.words[base + slot];
            if xor {
                *w ^= words.get(next);
            } else {
                let p = PointWord(*w);
                *w = p.with_ao((p.0 as u8).wrapping_sub(msg.data[next])).0;
            }
            next += 1;
        }
    }
}

/// Cost of one journaled write beyond the bytes it overwrites (spec 9): an
/// upper bound on the size of a journal entry.
const WRITE_COST: u64 = 32;

/// Charges a write that overwrites `bytes` to a frame's journal budget.
pub(super) fn spend(budget: &mut u64, bytes: usize) -> Result<(), MessageError> {
    let cost = WRITE_COST + bytes as u64;
    if cost > *budget {
        return Err(MessageError::ResourceLimit {
            needed: cost,
            limit: *budget,
        });
    }
    *budget -= cost;
    Ok(())
}

pub(super) struct Journal<'a> {
    pub(super) undo: &'a mut Vec<Undo>,
    pub(super) words: &'a mut Vec<u32>,
    pub(super) entries: &'a mut Vec<BucketEntry>,
    pub(super) budget: &'a mut u64,
}

impl Journal<'_> {
    /// Charges one write that overwrites `bytes` to the frame's budget.
    pub(super) fn spend(&mut self, bytes: usize) -> Result<(), MessageError> {
        spend(self.budget, bytes)
    }
}

/// Mutable access to one instance while a message applies, journaling
/// every write and recording changed ranges.
pub(super) struct Edit<'a> {
    pub(super) instance: u32,
    pub(super) def: InstanceDef,
    pub(super) words: &'a mut Vec<u32>,
    pub(super) buckets: &'a mut Vec<BucketEntry>,
    pub(super) journal: Option<Journal<'a>>,
    pub(super) changes: &'a mut Changes,
}

impl Edit<'_> {
    pub(super) fn cell_range(&self, cell: u32) -> Result<Range<usize>, MessageError> {
        if cell >= self.def.cell_pool {
            return Err(MessageError::CellIndex(cell));
        }
        let cap = self.def.cell_capacity as usize;
        Ok(cell as usize * cap..(cell as usize + 1) * cap)
    }

    /// Charges a cell write and saves the words it overwrites.
    pub(super) fn save_words(&mut self, range: Range<usize>) -> Result<(), MessageError> {
        self.charge_words(range.clone())?;
        if let Some(j) = &mut self.journal {
            j.undo.push(Undo::Words {
                instance: self.instance,
                start: range.start as u32,
                len: range.len() as u8,
                saved: j.words.len() as u32,
            });
            j.words.extend_from_slice(&self.words[range]);
        }
        Ok(())
    }

    /// Charges a cell write that an inverse will undo: budget and change
    /// list, no copy.
    pub(super) fn charge_words(&mut self, range: Range<usize>) -> Result<(), MessageError> {
        if let Some(j) = &mut self.journal {
            j.spend(range.len() * 4)?;
        }
        let r = range.start as u32..range.end as u32;
        push_change(self.changes, Change::Words(self.instance, r));
        Ok(())
    }

    pub(super) fn save_entries(&mut self, range: Range<usize>) -> Result<(), MessageError> {
        if let Some(j) = &mut self.journal {
            j.spend(range.len() * 8)?;
            j.undo.push(Undo::Entries {
                instance: self.instance,
                start: range.start as u32,
                len: range.len() as u8,
                saved: j.entries.len() as u32,
            });
            j.entries.extend_from_slice(&self.buckets[range.clone()]);
        }
        let r = range.start as u32..range.end as u32;
        push_change(self.changes, Change::Buckets(self.instance, r));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn journal_entries_stay_small() {
        assert!(std::mem::size_of::<Undo>() as u64 <= WRITE_COST);
        assert!(std::mem::size_of::<super::super::Transform>() <= 52);
    }
}
