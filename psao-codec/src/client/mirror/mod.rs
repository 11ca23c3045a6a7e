//! The client's copy of every instance grid, updated frame by frame.
//!
//! A frame is applied whole or not at all: every write first saves what it
//! overwrites in a journal, and an error rolls the journal back. Buckets and
//! words live in flat arrays (`[BucketEntry]`, `[u32]`) that a renderer can
//! upload to a GPU as they are; [`Mirror::take_changes`] tells which ranges
//! changed since the last call.

use std::collections::BTreeMap;
use std::ops::Range;

use crate::error::{DecodeError, MessageError};
use crate::grid::MAX_CELL_CAPACITY;
use crate::grid::{BucketEntry, InstanceDef};
use crate::limits::Limits;
use crate::wire::frame::{FrameView, Located};
use crate::wire::message::{BucketsMsg, CellsMsg, Message, Reader};
use crate::wire::point::PointWord;
use crate::wire::sequence::is_newer;

/// An instance-local to world transform with its own sequence number.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Transform sequence: a transform only replaces an older one.
    pub sequence: u32,
    /// Column-major 3x4 affine matrix (x axis, y axis, z axis, translation).
    pub matrix: [f32; 12],
}

impl Transform {
    /// The matrix as a glam affine transform.
    pub fn affine(&self) -> glam::Affine3A {
        glam::Affine3A::from_cols_slice(&self.matrix)
    }
}

/// The client's copy of one instance.
#[derive(Clone, Debug, PartialEq)]
pub struct InstanceMirror {
    def: InstanceDef,
    transform: Option<Transform>,
    buckets: Vec<BucketEntry>,
    words: Vec<u32>,
}

impl InstanceMirror {
    /// An empty instance of a (validated) definition.
    pub fn new(def: InstanceDef) -> InstanceMirror {
        InstanceMirror {
            def,
            transform: None,
            buckets: vec![BucketEntry::EMPTY; def.bucket_entries()],
            words: vec![0; def.cell_words()],
        }
    }

    /// The grid definition.
    pub fn def(&self) -> &InstanceDef {
        &self.def
    }

    /// The last transform received, if any.
    pub fn transform(&self) -> Option<&Transform> {
        self.transform.as_ref()
    }

    /// Bucket entries, `bucket_capacity` per bucket, occupied ones first.
    pub fn buckets(&self) -> &[BucketEntry] {
        &self.buckets
    }

    /// Point words, `cell_capacity` per cell, allocated ones first.
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// The cell index holding `key`, by the lookup the spec describes:
    /// scan the key's bucket until the first empty entry.
    pub fn find_cell(&self, key: u32) -> Option<u32> {
        let cap = self.def.bucket_capacity as usize;
        let b = self.def.bucket_of_key(key) as usize * cap;
        self.buckets[b..b + cap]
            .iter()
            .take_while(|e| !e.is_empty())
            .find(|e| e.key == key)
            .map(|e| e.cell)
    }

    /// The allocated words of a cell.
    pub fn cell_points(&self, cell: u32) -> impl Iterator<Item = PointWord> + '_ {
        let cap = self.def.cell_capacity as usize;
        let start = cell as usize * cap;
        self.words
            .get(start..start + cap)
            .unwrap_or(&[])
            .iter()
            .map(|&w| PointWord(w))
            .take_while(|w| w.is_allocated())
    }
}

/// A range of a mirror's state that changed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Change {
    /// The instance was defined or redefined: upload everything.
    Defined(u32),
    /// The instance was removed.
    Removed(u32),
    /// The instance's transform changed.
    Transform(u32),
    /// Bucket entries `range` of the instance changed.
    Buckets(u32, Range<u32>),
    /// Words `range` of the instance changed.
    Words(u32, Range<u32>),
}

/// What changed since the last [`Mirror::take_changes`] or
/// [`Mirror::clear_changes`]. After a rejected frame the list may
/// over-report (`all` set), never under-report.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Changes {
    /// Everything may have changed (a keyframe, or too many ranges to list).
    pub all: bool,
    /// Changed ranges in the order they were written; adjacent ranges merged.
    pub items: Vec<Change>,
}

/// Ranges listed before [`Changes::all`] is set instead.
const MAX_CHANGE_ITEMS: usize = 1 << 16;

/// What [`Mirror::apply`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// The frame was applied; the mirror is now at `sequence`.
    Applied {
        /// The mirror's new sequence.
        sequence: u32,
        /// Whether it was a keyframe.
        keyframe: bool,
    },
    /// The frame is older than (or as old as) the mirror's state: ignored.
    Stale {
        /// The frame's sequence.
        sequence: u32,
        /// The mirror's sequence.
        have: u32,
    },
    /// The frame does not apply to the mirror's state: a frame was missed,
    /// or the mirror has no keyframe yet. Ask the server for a keyframe.
    NeedKeyframe {
        /// The mirror's sequence, `None` before the first keyframe.
        have: Option<u32>,
        /// The sequence the frame applies to.
        base: u32,
        /// The frame's sequence.
        sequence: u32,
    },
}

/// One journal entry: what a write overwrote. Kept small (the instance is
/// boxed) because one is pushed per touched cell and bucket.
#[derive(Clone)]
enum Undo {
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

/// The client's copy of all instances at one sequence number. A clone is
/// a snapshot (a renderer can take one and draw from it while the live
/// mirror keeps receiving).
#[derive(Clone, Default)]
pub struct Mirror {
    sequence: Option<u32>,
    instances: BTreeMap<u32, InstanceMirror>,
    bytes: u64,
    changes: Changes,
    journal: Vec<Undo>,
    saved_words: Vec<u32>,
    saved_entries: Vec<BucketEntry>,
    frame: FrameState,
}

/// What the frame being applied has done so far.
#[derive(Clone, Default)]
struct FrameState {
    /// A keyframe: the whole previous state is kept aside, nothing is
    /// journaled.
    keyframe: bool,
    /// Instances defined, redefined or removed by this frame: their
    /// pre-frame version is already saved (or did not exist), so later
    /// writes to them need no journal.
    fresh: std::collections::BTreeSet<u32>,
    /// Bytes this frame may still journal, and still allocate in
    /// definitions (each starts at `max_mirror_bytes`).
    journal_budget: u64,
    alloc_budget: u64,
}

impl FrameState {
    fn start(keyframe: bool, limits: &Limits) -> FrameState {
        FrameState {
            keyframe,
            fresh: Default::default(),
            journal_budget: limits.max_mirror_bytes,
            alloc_budget: limits.max_mirror_bytes,
        }
    }

    /// Whether writes to `instance` must be journaled.
    fn journals(&self, instance: u32) -> bool {
        !self.keyframe && !self.fresh.contains(&instance)
    }
}

/// Largest journal buffers kept between frames; larger ones are shrunk.
const KEEP_JOURNAL_BYTES: usize = 4 << 20;

impl std::fmt::Debug for Mirror {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mirror")
            .field("sequence", &self.sequence)
            .field("instances", &self.instances.len())
            .field("bytes", &self.bytes)
            .finish()
    }
}

impl Mirror {
    /// An empty mirror waiting for its first keyframe.
    pub fn new() -> Mirror {
        Mirror::default()
    }

    /// The sequence of the last applied frame.
    pub fn sequence(&self) -> Option<u32> {
        self.sequence
    }

    /// One instance.
    pub fn instance(&self, id: u32) -> Option<&InstanceMirror> {
        self.instances.get(&id)
    }

    /// All instances by id.
    pub fn instances(&self) -> impl Iterator<Item = (u32, &InstanceMirror)> {
        self.instances.iter().map(|(&id, m)| (id, m))
    }

    /// Bytes held in bucket entries and words over all instances.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// A canonical text listing of the whole state: the sequence, then per
    /// instance its definition, transform, occupied bucket entries and
    /// allocated words with their decoded fields. The expected content of
    /// every vector in spec/vectors is written in this form.
    pub fn describe(&self) -> String {
        use std::fmt::Write;
        let mut out = String::new();
        match self.sequence {
            Some(s) => writeln!(out, "sequence {s}"),
            None => writeln!(out, "sequence none"),
        }
        .ok();
        for (id, m) in &self.instances {
            let d = m.def;
            let v = |v: glam::Vec3| format!("{} {} {}", v.x, v.y, v.z);
            writeln!(
                out,
                "instance {id} origin {} cell_size {} dims {} {} {} table_log2 {} \
                 bucket_capacity {} cell_capacity {} cell_pool {} point_format {} \
                 radius {} t_n {} t_d {}",
                v(d.origin),
                v(d.cell_size),
                d.dims.x,
                d.dims.y,
                d.dims.z,
                d.table_log2,
                d.bucket_capacity,
                d.cell_capacity,
                d.cell_pool,
                d.point_format,
                d.radius,
                d.t_n,
                d.t_d
            )
            .ok();
            if let Some(t) = m.transform {
                let floats: Vec<String> = t.matrix.iter().map(|f| f.to_string()).collect();
                writeln!(
                    out,
                    "transform {id} seq {} matrix {}",
                    t.sequence,
                    floats.join(" ")
                )
                .ok();
            }
            let cap = d.bucket_capacity as usize;
            for (i, e) in m.buckets.iter().enumerate().filter(|(_, e)| !e.is_empty()) {
                writeln!(out, "bucket {id} {} key {} cell {}", i / cap, e.key, e.cell).ok();
            }
            let cap = d.cell_capacity as usize;
            for (i, &w) in m.words.iter().enumerate().filter(|(_, w)| **w != 0) {
                let f = PointWord(w).fields();
                writeln!(
                    out,
                    "word {id} cell {} slot {} {w:08x} pos {} {} {} normal {:02x} ao {}",
                    i / cap,
                    i % cap,
                    f.position.x,
                    f.position.y,
                    f.position.z,
                    f.normal,
                    f.ao
                )
                .ok();
            }
        }
        out
    }

    /// Takes the list of what changed since the last call.
    pub fn take_changes(&mut self) -> Changes {
        std::mem::take(&mut self.changes)
    }

    /// What changed since the last [`clear_changes`](Self::clear_changes)
    /// or [`take_changes`](Self::take_changes). A renderer reads this after
    /// each frame, uploads those ranges, then clears it.
    pub fn changes(&self) -> &Changes {
        &self.changes
    }

    /// Forgets the recorded changes, keeping the list's memory for reuse.
    pub fn clear_changes(&mut self) {
        self.changes.all = false;
        self.changes.items.clear();
    }

    /// Applies a transform that arrived outside a frame (e.g. in a
    /// datagram). Returns whether it replaced the stored one (it does
    /// unless the stored one is newer or equal).
    pub fn apply_transform(
        &mut self,
        instance: u32,
        transform: Transform,
    ) -> Result<bool, MessageError> {
        if !transform.matrix.iter().all(|m| m.is_finite()) {
            return Err(MessageError::NonFiniteTransform);
        }
        let m = self
            .instances
            .get_mut(&instance)
            .ok_or(MessageError::UnknownInstance(instance))?;
        if m.transform
            .is_some_and(|t| !is_newer(transform.sequence, t.sequence))
        {
            return Ok(false);
        }
        m.transform = Some(transform);
        push_change(&mut self.changes, Change::Transform(instance));
        Ok(true)
    }

    /// Applies a checked frame: a keyframe replaces everything, a delta
    /// applies when its base is the mirror's sequence. On error the mirror
    /// is exactly as before.
    pub fn apply(&mut self, frame: &FrameView<'_>, limits: &Limits) -> Result<Event, DecodeError> {
        let h = *frame.header();
        if h.keyframe {
            if let Some(have) = self.sequence
                && is_newer(have, h.sequence)
            {
                return Ok(Event::Stale {
                    sequence: h.sequence,
                    have,
                });
            }
            let old = std::mem::take(&mut self.instances);
            let old_bytes = std::mem::replace(&mut self.bytes, 0);
            let old_changes = std::mem::take(&mut self.changes);
            self.frame = FrameState::start(true, limits);
            match self.apply_messages(frame, limits) {
                Ok(()) => {
                    self.changes = Changes {
                        all: true,
                        items: Vec::new(),
                    };
                }
                Err(e) => {
                    self.instances = old;
                    self.bytes = old_bytes;
                    self.changes = old_changes;
                    return Err(e);
                }
            }
        } else {
            let Some(have) = self.sequence.filter(|&s| s == h.base_sequence) else {
                return Ok(match self.sequence {
                    Some(have) if !is_newer(h.sequence, have) => Event::Stale {
                        sequence: h.sequence,
                        have,
                    },
                    have => Event::NeedKeyframe {
                        have,
                        base: h.base_sequence,
                        sequence: h.sequence,
                    },
                });
            };
            let _ = have;
            let mark = ChangeMark::of(&self.changes);
            let bytes = self.bytes;
            self.frame = FrameState::start(false, limits);
            let result = self.apply_messages(frame, limits);
            if let Err(e) = result {
                self.rollback(frame.payload());
                self.bytes = bytes;
                mark.restore(&mut self.changes);
                return Err(e);
            }
            self.clear_journal();
        }
        self.sequence = Some(h.sequence);
        Ok(Event::Applied {
            sequence: h.sequence,
            keyframe: h.keyframe,
        })
    }

    fn rollback(&mut self, payload: &[u8]) {
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

    fn clear_journal(&mut self) {
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

    fn apply_messages(
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
                if def.cell_of_key(key).is_none() {
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

#[derive(Clone, Copy)]
enum CellOp {
    Full,
    Xor,
    Ao,
}

/// Cost of one journaled write beyond the bytes it overwrites (spec 9): an
/// upper bound on the size of a journal entry.
const WRITE_COST: u64 = 32;

/// Charges a write that overwrites `bytes` to a frame's journal budget.
fn spend(budget: &mut u64, bytes: usize) -> Result<(), MessageError> {
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

struct Journal<'a> {
    undo: &'a mut Vec<Undo>,
    words: &'a mut Vec<u32>,
    entries: &'a mut Vec<BucketEntry>,
    budget: &'a mut u64,
}

impl Journal<'_> {
    /// Charges one write that overwrites `bytes` to the frame's budget.
    fn spend(&mut self, bytes: usize) -> Result<(), MessageError> {
        spend(self.budget, bytes)
    }
}

/// Mutable access to one instance while a message applies, journaling
/// every write and recording changed ranges.
struct Edit<'a> {
    instance: u32,
    def: InstanceDef,
    words: &'a mut Vec<u32>,
    buckets: &'a mut Vec<BucketEntry>,
    journal: Option<Journal<'a>>,
    changes: &'a mut Changes,
}

impl Edit<'_> {
    fn cell_range(&self, cell: u32) -> Result<Range<usize>, MessageError> {
        if cell >= self.def.cell_pool {
            return Err(MessageError::CellIndex(cell));
        }
        let cap = self.def.cell_capacity as usize;
        Ok(cell as usize * cap..(cell as usize + 1) * cap)
    }

    /// Charges a cell write and saves the words it overwrites.
    fn save_words(&mut self, range: Range<usize>) -> Result<(), MessageError> {
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
    fn charge_words(&mut self, range: Range<usize>) -> Result<(), MessageError> {
        if let Some(j) = &mut self.journal {
            j.spend(range.len() * 4)?;
        }
        let r = range.start as u32..range.end as u32;
        push_change(self.changes, Change::Words(self.instance, r));
        Ok(())
    }

    fn save_entries(&mut self, range: Range<usize>) -> Result<(), MessageError> {
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

/// The change list as it was before a delta, to restore on rollback. The
/// restored list may over-report (never under-report): if the failed frame
/// overflowed the list into `all`, `all` stays set.
struct ChangeMark {
    all: bool,
    len: usize,
    last: Option<Change>,
}

impl ChangeMark {
    fn of(changes: &Changes) -> ChangeMark {
        ChangeMark {
            all: changes.all,
            len: changes.items.len(),
            last: changes.items.last().cloned(),
        }
    }

    fn restore(self, changes: &mut Changes) {
        if changes.all && !self.all {
            return;
        }
        changes.items.truncate(self.len);
        if let (Some(last), Some(slot)) = (self.last, changes.items.last_mut()) {
            *slot = last;
        }
    }
}

fn push_change(changes: &mut Changes, change: Change) {
    if changes.all {
        return;
    }
    if let Some(last) = changes.items.last_mut() {
        match (last, &change) {
            (Change::Words(a, ra), Change::Words(b, rb))
            | (Change::Buckets(a, ra), Change::Buckets(b, rb))
                if a == b && ra.end >= rb.start && ra.start <= rb.start =>
            {
                ra.end = ra.end.max(rb.end);
                return;
            }
            _ => {}
        }
    }
    if changes.items.len() >= MAX_CHANGE_ITEMS {
        changes.all = true;
        changes.items.clear();
        return;
    }
    changes.items.push(change);
}

#[cfg(test)]
mod tests {
    #[test]
    fn journal_entries_stay_small() {
        assert!(std::mem::size_of::<super::Undo>() as u64 <= super::WRITE_COST);
        assert!(std::mem::size_of::<super::Transform>() <= 52);
    }
}
