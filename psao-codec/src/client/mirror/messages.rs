//! Applying the messages of a frame to the mirror, one by one, checking
//! each against the spec as it writes (spec/wire-format.md 6-8).

use super::changes::{Change, push_change};
use super::journal::{Edit, Journal, Undo, spend};
use super::{InstanceMirror, Mirror, Transform};
use crate::error::{DecodeError, MessageError};
use crate::grid::{BucketEntry, InstanceDef, MAX_CELL_CAPACITY};
use crate::limits::Limits;
use crate::wire::frame::{FrameView, Located};
use crate::wire::message::{BucketsMsg, CellsMsg, Message};
use crate::wire::point::PointWord;
use crate::wire::sequence::is_newer;

impl Mirror {
    pub(super) fn apply_messages(
        &mut self,
        frame: &FrameView<'_>,
        limits: &Limits,
    ) -> Result<(), DecodeError> {
        for located in frame.messages() {
            let located = located?;
            self.apply_message(&located, limits)
                .map_err(|e| located.error(e))?;
        }
        Ok(())
    }

    fn apply_message(&mut self, at: &Located<'_>, limits: &Limits) -> Result<(), MessageError> {
        match at.message {
            Message::EndOfFrame => Ok(()),
            Message::DefineInstance { instance, def } => self.define(instance, def, limits),
            Message::RemoveInstance { instance } => {
                let old = self
                    .instances
                    .remove(&instance)
                    .ok_or(MessageError::UnknownInstance(instance))?;
                self.bytes -= old.def.mirror_bytes() as u64;
                self.replaced(instance, Some(old));
                push_change(&mut self.changes, Change::Removed(instance));
                Ok(())
            }
            Message::Transform {
                instance,
                transform_sequence,
                matrix,
            } => {
                let m = self
                    .instances
                    .get_mut(&instance)
                    .ok_or(MessageError::UnknownInstance(instance))?;
                if m.transform
                    .is_some_and(|t| !is_newer(transform_sequence, t.sequence))
                {
                    return Ok(());
                }
                if self.frame.journals(instance) {
                    spend(&mut self.frame.journal_budget, 48)?; // 32 + 48 = 80
                    self.journal
                        .push(Undo::Transform(instance, m.transform.map(Box::new)));
                }
                m.transform = Some(Transform {
                    sequence: transform_sequence,
                    matrix,
                });
                push_change(&mut self.changes, Change::Transform(instance));
                Ok(())
            }
            Message::Buckets(msg) => self.buckets(msg),
            Message::CellsFull(msg) => self.cells(msg, CellOp::Full, at.offset),
            Message::CellsXor(msg) => self.cells(msg, CellOp::Xor, at.offset),
            Message::CellsAo(msg) => self.cells(msg, CellOp::Ao, at.offset),
            Message::CellsFree { instance, cells } => {
                let mut state = self.edit(instance)?;
                for cell in cells.iter() {
                    let range = state.cell_range(cell)?;
                    state.save_words(range.clone())?;
                    state.words[range].fill(0);
                }
                Ok(())
            }
        }
    }

    fn define(
        &mut self,
        instance: u32,
        def: InstanceDef,
        limits: &Limits,
    ) -> Result<(), MessageError> {
        let old_bytes = self
            .instances
            .get(&instance)
            .map_or(0, |m| m.def.mirror_bytes() as u64);
        let is_new = !self.instances.contains_key(&instance);
        if is_new && self.instances.len() as u64 >= limits.max_instances as u64 {
            return Err(MessageError::InstanceLimit {
                limit: limits.max_instances,
            });
        }
        if def.table_log2 > limits.max_table_log2 {
            return Err(MessageError::ResourceLimit {
                needed: def.table_size() as u64,
                limit: 1u64 << limits.max_table_log2,
            });
        }
        if def.cell_pool > limits.max_cell_pool {
            return Err(MessageError::ResourceLimit {
                needed: def.cell_pool as u64,
                limit: limits.max_cell_pool as u64,
            });
        }
        let needed = self.bytes - old_bytes + def.mirror_bytes() as u64;
        if needed > limits.max_mirror_bytes {
            return Err(MessageError::ResourceLimit {
                needed,
                limit: limits.max_mirror_bytes,
            });
        }
        let alloc = def.mirror_bytes() as u64;
        if alloc > self.frame.alloc_budget {
            return Err(MessageError::ResourceLimit {
                needed: limits.max_mirror_bytes - self.frame.alloc_budget + alloc,
                limit: limits.max_mirror_bytes,
            });
        }
        self.frame.alloc_budget -= alloc;
        let old = self.instances.insert(instance, InstanceMirror::new(def));
        self.bytes = needed;
        self.replaced(instance, old);
        push_change(&mut self.changes, Change::Defined(instance));
        Ok(())
    }

    /// Records that `instance` was replaced or removed by this frame. Its
    /// pre-frame version is journaled the first time only; versions the
    /// frame itself created are simply dropped.
    fn replaced(&mut self, instance: u32, old: Option<InstanceMirror>) {
        if self.frame.journals(instance) {
            self.journal
                .push(Undo::Instance(instance, old.map(Box::new)));
        }
        self.frame.fresh.insert(instance);
    }

    fn edit(&mut self, instance: u32) -> Result<Edit<'_>, MessageError> {
        let journal = self.frame.journals(instance);
        let m = self
            .instances
            .get_mut(&instance)
            .ok_or(MessageError::UnknownInstance(instance))?;
        Ok(Edit {
            instance,
            def: m.def,
            words: &mut m.words,
            buckets: &mut m.buckets,
            journal: journal.then_some(Journal {
                undo: &mut self.journal,
                words: &mut self.saved_words,
                entries: &mut self.saved_entries,
                budget: &mut self.frame.journal_budget,
            }),
            changes: &mut self.changes,
        })
    }

    fn buckets(&mut self, msg: BucketsMsg<'_>) -> Result<(), MessageError> {
        let mut state = self.edit(msg.instance)?;
        let def = state.def;
        let cap = def.bucket_capacity as usize;
        let mut entry = 0usize;
        for (bucket, &count) in msg.buckets.iter().zip(msg.counts) {
            if bucket >= def.table_size() {
                return Err(MessageError::BucketIndex(bucket));
            }
            if count as usize > cap {
                return Err(MessageError::BucketOverCapacity { bucket });
            }
            let start = bucket as usize * cap;
            state.save_entries(start..start + cap)?;
            let slots = &mut state.buckets[start..start + cap];
            for i in 0..count as usize {
                let key = msg.keys.get(entry + i);
                let cell = msg.cells.get(entry + i);
                if def.link_of_key(key).is_none() {
                    return Err(MessageError::KeyNotInGrid(key));
                }
                if def.bucket_of_key(key) != bucket {
                    return Err(MessageError::KeyWrongBucket { key, bucket });
                }
                if cell >= def.cell_pool {
                    return Err(MessageError::CellIndex(cell));
                }
                if slots[..i].iter().any(|e| e.key == key) {
                    return Err(MessageError::DuplicateKey { key, bucket });
                }
                slots[i] = BucketEntry { key, cell };
            }
            slots[count as usize..].fill(BucketEntry::EMPTY);
            entry += count as usize;
        }
        Ok(())
    }

    fn cells(&mut self, msg: CellsMsg<'_>, op: CellOp, offset: u64) -> Result<(), MessageError> {
        let mut state = self.edit(msg.instance)?;
        // XOR and AO deltas are undone by their inverse: one journal entry
        // for the whole message, updated with how many cells applied.
        let inverse = match op {
            CellOp::Full => None,
            CellOp::Xor | CellOp::Ao => state.journal.as_mut().map(|j| {
                j.undo.push(Undo::Inverse {
                    instance: msg.instance,
                    offset: offset as u32,
                    applied: 0,
                });
                j.undo.len() - 1
            }),
        };
        let mut applied = 0u32;
        let result = apply_cells(&mut state, &msg, op, inverse.is_some(), &mut applied);
        if let (Some(i), Some(j)) = (inverse, state.journal.as_mut())
            && let Some(Undo::Inverse { applied: a, .. }) = j.undo.get_mut(i)
        {
            *a = applied;
        }
        result
    }
}

/// Applies the cells of one message, counting in `applied` the cells
/// written. With `inverse`, XOR and AO cells are charged but not saved, and
/// each cell is checked before it is written, so `applied` whole cells are
/// exactly what an inverse must undo.
fn apply_cells(
    state: &mut Edit<'_>,
    msg: &CellsMsg<'_>,
    op: CellOp,
    inverse: bool,
    applied: &mut u32,
) -> Result<(), MessageError> {
    let cap = state.def.cell_capacity;
    let words = msg.words();
    let mut next = 0usize;
    for (cell, &per) in msg.cells.iter().zip(msg.per_cell) {
        let range = state.cell_range(cell)?;
        let beyond = match op {
            CellOp::Full => per > cap,
            CellOp::Xor | CellOp::Ao => (per as u16) >> cap != 0,
        };
        if beyond {
            return Err(MessageError::SlotBeyondCapacity { cell });
        }
        if inverse {
            state.charge_words(range.clone())?;
        } else {
            state.save_words(range.clone())?;
        }
        let w = &mut state.words[range];
        match op {
            CellOp::Full => {
                for (slot, word) in w.iter_mut().enumerate() {
                    *word = 0;
                    if slot < per as usize {
                        let listed = words.get(next);
                        next += 1;
                        let p = PointWord(listed);
                        if !p.is_allocated() || !p.is_valid() {
                            return Err(MessageError::InvalidWord { cell, word: listed });
                        }
                        *word = listed;
                    }
                }
            }
            CellOp::Xor => {
                let mut buf = [0u32; MAX_CELL_CAPACITY as usize];
                let new = &mut buf[..w.len()];
                new.copy_from_slice(w);
                let mut mask = per;
                while mask != 0 {
                    let slot = mask.trailing_zeros() as usize;
                    new[slot] ^= words.get(next);
                    next += 1;
                    mask &= mask - 1;
                }
                check_cell(cell, new)?;
                w.copy_from_slice(new);
            }
            CellOp::Ao => {
                let mut mask = per;
                while mask != 0 {
                    let slot = mask.trailing_zeros();
                    if !PointWord(w[slot as usize]).is_allocated() {
                        return Err(MessageError::AoToEmptySlot {
                            cell,
                            slot: slot as u8,
                        });
                    }
                    mask &= mask - 1;
                }
                let mut mask = per;
                while mask != 0 {
                    let slot = mask.trailing_zeros() as usize;
                    let p = PointWord(w[slot]);
                    w[slot] = p.with_ao((p.0 as u8).wrapping_add(msg.data[next])).0;
                    next += 1;
                    mask &= mask - 1;
                }
            }
        }
        *applied += 1;
    }
    Ok(())
}

#[derive(Clone, Copy)]
enum CellOp {
    Full,
    Xor,
    Ao,
}

/// Every word valid; allocated words form a prefix (compaction).
fn check_cell(cell: u32, words: &[u32]) -> Result<(), MessageError> {
    let mut empty_seen = false;
    for &w in words {
        let p = PointWord(w);
        if !p.is_valid() {
            return Err(MessageError::InvalidWord { cell, word: w });
        }
        if p.is_allocated() {
            if empty_seen {
                return Err(MessageError::Compaction { cell });
            }
        } else {
            empty_seen = true;
        }
    }
    Ok(())
}
