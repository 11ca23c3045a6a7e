//! The client's copy of every instance grid, updated frame by frame.
//!
//! A frame is applied whole or not at all: every write first saves what it
//! overwrites in a journal, and an error rolls the journal back. Buckets and
//! words live in flat arrays (`[BucketEntry]`, `[u32]`) that a renderer can
//! upload to a GPU as they are; [`Mirror::take_changes`] tells which ranges
//! changed since the last call.
//!
//! Here: the state and the frame-level decisions (keyframe, delta, stale,
//! gap); `messages` applies each message, `journal` saves and rolls back,
//! `changes` lists what a renderer must upload.

mod changes;
mod digest;
mod journal;
mod messages;

use std::collections::BTreeMap;

pub use changes::{Change, Changes};
use changes::{ChangeMark, push_change};
use journal::{FrameState, Undo};

use crate::error::{DecodeError, MessageError};
use crate::grid::{BucketEntry, InstanceDef};
use crate::limits::Limits;
use crate::wire::frame::FrameView;
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
        self.find_in(key, self.def.bucket_of_key(key))
    }

    /// The cell index filed under `key` in `bucket`.
    fn find_in(&self, key: u32, bucket: u32) -> Option<u32> {
        let cap = self.def.bucket_capacity as usize;
        let b = bucket as usize * cap;
        self.buckets[b..b + cap]
            .iter()
            .take_while(|e| !e.is_empty())
            .find(|e| e.key == key)
            .map(|e| e.cell)
    }

    /// The pool cells holding grid cell `key`'s points: the cell the key
    /// names, then, with [`InstanceDef::overflow`], each link of its
    /// overflow chain while the one before it is full (spec/wire-format.md
    /// 7.4). `key` must be a cell's own key (eq. 1).
    pub fn chain(&self, key: u32) -> impl Iterator<Item = u32> + '_ {
        self.chain_head(key)
            .into_iter()
            .flat_map(move |head| self.chain_from(key, head))
    }

    /// The first pool cell of grid cell `key`'s chain (the cell the key
    /// names), or `None`. `key` must be a cell's own key (eq. 1): unlike
    /// [`find_cell`](Self::find_cell), this does not work out which link a
    /// key names (two divisions).
    pub fn chain_head(&self, key: u32) -> Option<u32> {
        self.find_in(key, self.def.bucket_of_link(key, 0))
    }

    /// [`chain`](Self::chain) from its first pool cell `head`, found
    /// already (by [`chain_head`](Self::chain_head) on `key`).
    pub fn chain_from(&self, key: u32, head: u32) -> impl Iterator<Item = u32> + '_ {
        let links = self.def.max_links();
        let mut next = Some(head);
        let mut link = 0u8;
        std::iter::from_fn(move || {
            let cell = next.take()?;
            if link < links && self.cell_full(cell) {
                link += 1;
                next = self.find_in(
                    self.def.link_key(key, link),
                    self.def.bucket_of_link(key, link),
                );
            }
            Some(cell)
        })
    }

    /// Whether every slot of a cell holds an allocated word.
    fn cell_full(&self, cell: u32) -> bool {
        let cap = self.def.cell_capacity as usize;
        let last = cell as usize * cap + cap - 1;
        self.words
            .get(last)
            .is_some_and(|&w| PointWord(w).is_allocated())
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

/// What [`Mirror::apply`] did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
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
                 bucket_capacity {} cell_capacity {} cell_pool {} point_format {}{} \
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
                if d.overflow { " overflow" } else { "" },
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
}
