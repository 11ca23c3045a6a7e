//! The server side of the wire: turns instance changes, transforms and
//! [`GridTable`] dirty sets into frames with sequence numbers.
//!
//! Deltas advance the sequence; a keyframe carries the state at the current
//! sequence without advancing it, so a late joiner can take a keyframe and
//! then the next delta that every other client receives.

use bytes::Bytes;

use crate::error::EncodeError;
use crate::grid::InstanceDef;
use crate::limits::Limits;
use crate::server::table::{DirtySet, GridTable};
use crate::wire::compress::Compressor;
use crate::wire::compression::Compression;
use crate::wire::header::{FrameHeader, HEADER_LEN, frame_checksum};
use crate::wire::message::{kind, write};
use crate::wire::point::AO_MASK;

/// How frames are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncoderConfig {
    /// Payload compression. A frame whose compressed payload would not be
    /// smaller is sent uncompressed.
    pub compression: Compression,
    /// zstd level (the paper: 15; 3 is zstd's default and much faster).
    pub zstd_level: i32,
    /// Whether frames carry a CRC-32 (for transports without integrity).
    pub checksum: bool,
    /// The receivers' limits: a frame beyond them is not produced
    /// ([`EncodeError::ReceiverLimit`]).
    pub limits: Limits,
}

impl Default for EncoderConfig {
    fn default() -> Self {
        EncoderConfig {
            compression: if cfg!(feature = "zstd") {
                Compression::Zstd
            } else if cfg!(feature = "lz4") {
                Compression::Lz4
            } else {
                Compression::None
            },
            zstd_level: 3,
            checksum: true,
            limits: Limits::default(),
        }
    }
}

/// Counts of what a frame holds, for statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameStats {
    /// Messages, `EndOfFrame` included.
    pub messages: u32,
    /// Buckets sent.
    pub buckets: u32,
    /// Cells sent whole.
    pub cells_full: u32,
    /// Cells sent as XOR deltas.
    pub cells_xor: u32,
    /// Cells sent as AO deltas.
    pub cells_ao: u32,
    /// Cells freed.
    pub cells_freed: u32,
    /// Points whose words were sent (whole, XOR or AO).
    pub points: u32,
    /// Payload bytes before compression.
    pub payload_bytes: u32,
    /// Frame bytes on the wire.
    pub frame_bytes: u32,
}

/// An encoded frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EncodedFrame {
    /// The bytes to send.
    pub bytes: Bytes,
    /// Its sequence.
    pub sequence: u32,
    /// Whether it is a keyframe.
    pub keyframe: bool,
    /// What it holds.
    pub stats: FrameStats,
}

/// Writes frames and numbers them.
#[derive(Debug)]
pub struct Encoder {
    config: EncoderConfig,
    sequence: u32,
    payload: Vec<u8>,
    scratch: Scratch,
    compressor: Compressor,
    /// The frame begun last, numbered over all encoders of the process
    /// ([`next_generation`]), so that a [`PausedFrame`] resumes only the
    /// frame it was paused from, on the encoder it came from.
    generation: u64,
}

#[derive(Debug, Default)]
struct Scratch {
    indices: Vec<u32>,
    per_cell: Vec<u8>,
    words: Vec<u32>,
    bytes: Vec<u8>,
}

impl Encoder {
    /// An encoder whose state starts at sequence 0.
    pub fn new(config: EncoderConfig) -> Encoder {
        Encoder::starting_at(config, 0)
    }

    /// An encoder whose state starts at `sequence` (the first delta is
    /// `sequence + 1`).
    pub fn starting_at(config: EncoderConfig, sequence: u32) -> Encoder {
        Encoder {
            config,
            sequence,
            payload: Vec::new(),
            scratch: Scratch::default(),
            compressor: Compressor::default(),
            generation: 0,
        }
    }

    /// The sequence of the state encoded so far.
    pub fn sequence(&self) -> u32 {
        self.sequence
    }

    /// The configuration.
    pub fn config(&self) -> &EncoderConfig {
        &self.config
    }

    /// Changes the configuration for the next frames.
    pub fn set_config(&mut self, config: EncoderConfig) {
        self.config = config;
    }

    /// Starts a delta frame (sequence + 1, based on the current sequence).
    pub fn delta(&mut self) -> FrameBuilder<'_> {
        self.begin(false)
    }

    /// Starts a keyframe of the state at the current sequence. Fill it with
    /// [`FrameBuilder::snapshot`] for every instance.
    pub fn keyframe(&mut self) -> FrameBuilder<'_> {
        self.begin(true)
    }

    fn begin(&mut self, keyframe: bool) -> FrameBuilder<'_> {
        self.payload.clear();
        self.generation = next_generation();
        FrameBuilder {
            encoder: self,
            keyframe,
            stats: FrameStats::default(),
        }
    }

    /// Takes up a frame [paused](FrameBuilder::pause) from this encoder.
    /// Returns `None`, changing nothing, when a frame was begun since (the
    /// paused frame's messages are gone) or the frame came from another
    /// encoder.
    pub fn resume(&mut self, paused: PausedFrame) -> Option<FrameBuilder<'_>> {
        if paused.generation != self.generation {
            return None;
        }
        Some(FrameBuilder {
            encoder: self,
            keyframe: paused.keyframe,
            stats: paused.stats,
        })
    }
}

impl Encoder {
    /// Drops a paused frame instead of finishing it. A delta that already
    /// holds messages takes its sequence number, as a delta refused by
    /// [`FrameBuilder::finish`] does: changes it took from a table (its
    /// dirty set) are lost to clients, who then see a gap and ask for a
    /// keyframe instead of silently diverging. A stale paused frame
    /// (see [`resume`](Self::resume)) changes nothing.
    pub fn abandon(&mut self, paused: PausedFrame) {
        if paused.generation != self.generation {
            return;
        }
        self.generation = next_generation();
        self.payload.clear();
        if !paused.keyframe && paused.stats.messages > 0 {
            self.sequence = self.sequence.wrapping_add(1);
        }
    }
}

/// A number no other frame of this process was begun with (64 bits: no
/// wrap in practice).
fn next_generation() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A frame put aside by [`FrameBuilder::pause`]: its messages stay in the
/// encoder, and [`Encoder::resume`] takes it up again. For callers that
/// cannot hold the builder's borrow across calls (the C API builds a frame
/// over several calls).
#[derive(Debug)]
pub struct PausedFrame {
    generation: u64,
    keyframe: bool,
    stats: FrameStats,
}

impl PausedFrame {
    /// Whether it is a keyframe.
    pub fn is_keyframe(&self) -> bool {
        self.keyframe
    }

    /// Messages added so far (`EndOfFrame` not yet among them).
    pub fn messages(&self) -> u32 {
        self.stats.messages
    }
}

/// One frame being written. Messages apply in the order they are added.
#[derive(Debug)]
pub struct FrameBuilder<'e> {
    encoder: &'e mut Encoder,
    keyframe: bool,
    stats: FrameStats,
}

impl FrameBuilder<'_> {
    /// Defines (or redefines, clearing it on the client) an instance.
    pub fn define_instance(&mut self, instance: u32, def: &InstanceDef) -> Result<(), EncodeError> {
        def.validate()?;
        write::define(&mut self.encoder.payload, instance, def);
        self.stats.messages += 1;
        Ok(())
    }

    /// Removes an instance.
    pub fn remove_instance(&mut self, instance: u32) {
        write::remove(&mut self.encoder.payload, instance);
        self.stats.messages += 1;
    }

    /// Sets an instance's local-to-world transform (column-major 3x4). A
    /// client keeps the transform with the newest `transform_sequence`.
    pub fn transform(&mut self, instance: u32, transform_sequence: u32, matrix: &[f32; 12]) {
        write::transform(
            &mut self.encoder.payload,
            instance,
            transform_sequence,
            matrix,
        );
        self.stats.messages += 1;
    }

    /// Writes everything that changed in `table` since its last dirty set
    /// was taken, and takes it.
    pub fn changes(&mut self, table: &mut GridTable) {
        let dirty = table.take_dirty();
        self.dirty_set(table, &dirty);
    }

    /// Writes a dirty set already taken from `table`. The table MUST NOT have
    /// changed since the set was taken: the words it holds now are what the
    /// frame sends, and the set's old words are what clients hold.
    pub fn dirty_set(&mut self, table: &GridTable, dirty: &DirtySet) {
        let id = table.id();
        let cap = table.def().cell_capacity as usize;
        let mut free = Vec::new();
        let mut full = Vec::new();
        let mut xor = Vec::new();
        let mut ao = Vec::new();
        for d in &dirty.cells {
            let new = table.cell(d.cell);
            let old = &d.old[..cap];
            if new == old {
                continue;
            }
            if new.iter().all(|&w| w == 0) {
                free.push(d.cell);
            } else if old.iter().all(|&w| w == 0) {
                full.push(d.cell);
            } else if old.iter().zip(new).all(|(o, n)| (o ^ n) & !AO_MASK == 0) {
                ao.push((d.cell, old));
            } else {
                xor.push((d.cell, old));
            }
        }
        self.cells_free(id, &free);
        self.cells_full(table, &full);
        self.cells_delta(table, &xor, kind::CELLS_XOR);
        self.cells_delta(table, &ao, kind::CELLS_AO);
        self.buckets(table, dirty.buckets.iter().copied());
    }

    /// Writes the whole state of `table`: its definition, then every
    /// occupied bucket and allocated cell. Fails if the table has changes
    /// not yet sent in a delta (the keyframe would not match its sequence):
    /// a server that fills a table before its first client either sends
    /// those changes as a delta or discards them with
    /// [`GridTable::take_dirty`].
    pub fn snapshot(&mut self, table: &GridTable) -> Result<(), EncodeError> {
        if table.has_pending() {
            return Err(EncodeError::PendingChanges(table.id()));
        }
        self.define_instance(table.id(), table.def())?;
        let buckets = (0..table.def().table_size()).filter(|&b| !table.bucket(b).is_empty());
        self.buckets(table, buckets);
        let cells: Vec<u32> = (0..table.def().cell_pool)
            .filter(|&c| table.cell_len(c) > 0)
            .collect();
        self.cells_full(table, &cells);
        Ok(())
    }

    fn cells_free(&mut self, instance: u32, cells: &[u32]) {
        if cells.is_empty() {
            return;
        }
        let out = &mut self.encoder.payload;
        write::list_head(out, kind::CELLS_FREE, instance, cells.len());
        write::index_list(out, cells.iter().copied());
        self.stats.messages += 1;
        self.stats.cells_freed += cells.len() as u32;
    }

    fn cells_full(&mut self, table: &GridTable, cells: &[u32]) {
        if cells.is_empty() {
            return;
        }
        let s = &mut self.encoder.scratch;
        s.per_cell.clear();
        s.words.clear();
        for &c in cells {
            let n = table.cell_len(c);
            s.per_cell.push(n);
            s.words.extend_from_slice(&table.cell(c)[..n as usize]);
        }
        let out = &mut self.encoder.payload;
        write::list_head(out, kind::CELLS_FULL, table.id(), cells.len());
        write::index_list(out, cells.iter().copied());
        out.extend_from_slice(&s.per_cell);
        write::planar(out, &s.words);
        self.stats.messages += 1;
        self.stats.cells_full += cells.len() as u32;
        self.stats.points += s.words.len() as u32;
    }

    fn cells_delta(&mut self, table: &GridTable, cells: &[(u32, &[u32])], t: u8) {
        if cells.is_empty() {
            return;
        }
        let s = &mut self.encoder.scratch;
        s.per_cell.clear();
        s.words.clear();
        s.bytes.clear();
        for &(c, old) in cells {
            let mut mask = 0u8;
            for (slot, (&o, &n)) in old.iter().zip(table.cell(c)).enumerate() {
                if o != n {
                    mask |= 1 << slot;
                    if t == kind::CELLS_AO {
                        s.bytes.push((n as u8).wrapping_sub(o as u8));
                    } else {
                        s.words.push(o ^ n);
                    }
                }
            }
            s.per_cell.push(mask);
        }
        let out = &mut self.encoder.payload;
        write::list_head(out, t, table.id(), cells.len());
        write::index_list(out, cells.iter().map(|c| c.0));
        out.extend_from_slice(&s.per_cell);
        if t == kind::CELLS_AO {
            out.extend_from_slice(&s.bytes);
            self.stats.cells_ao += cells.len() as u32;
            self.stats.points += s.bytes.len() as u32;
        } else {
            write::planar(out, &s.words);
            self.stats.cells_xor += cells.len() as u32;
            self.stats.points += s.words.len() as u32;
        }
        self.stats.messages += 1;
    }

    fn buckets(&mut self, table: &GridTable, buckets: impl Iterator<Item = u32>) {
        let s = &mut self.encoder.scratch;
        s.indices.clear();
        s.per_cell.clear();
        s.words.clear();
        s.bytes.clear();
        let mut cells = Vec::new();
        for b in buckets {
            let entries = table.bucket(b);
            s.indices.push(b);
            s.per_cell.push(entries.len() as u8);
            s.words.extend(entries.iter().map(|e| e.key));
            cells.extend(entries.iter().map(|e| e.cell));
        }
        if s.indices.is_empty() {
            return;
        }
        let out = &mut self.encoder.payload;
        write::list_head(out, kind::BUCKETS, table.id(), s.indices.len());
        write::index_list(out, s.indices.iter().copied());
        out.extend_from_slice(&s.per_cell);
        write::planar(out, &s.words);
        write::planar(out, &cells);
        self.stats.messages += 1;
        self.stats.buckets += s.indices.len() as u32;
    }

    /// Puts the frame aside, keeping its messages in the encoder, to go on
    /// with [`Encoder::resume`].
    pub fn pause(self) -> PausedFrame {
        PausedFrame {
            generation: self.encoder.generation,
            keyframe: self.keyframe,
            stats: self.stats,
        }
    }

    /// Whether no message was added yet.
    pub fn is_empty(&self) -> bool {
        self.stats.messages == 0
    }

    /// Finishes the frame. A delta with no message is not a frame: it
    /// returns `None` and the sequence does not advance.
    ///
    /// A compression that is not compiled in, or that fails, falls back to
    /// an uncompressed payload. A frame beyond the receivers' limits
    /// ([`EncoderConfig::limits`]) is an error; if it was a delta, its
    /// changes are lost to clients, so the encoder skips its sequence
    /// number: every client then sees a gap and asks for a keyframe instead
    /// of silently diverging.
    pub fn finish(mut self) -> Result<Option<EncodedFrame>, EncodeError> {
        if !self.keyframe && self.is_empty() {
            return Ok(None);
        }
        match self.build() {
            Ok(frame) => Ok(Some(frame)),
            Err(e) => {
                if !self.keyframe {
                    self.encoder.sequence = self.encoder.sequence.wrapping_add(1);
                }
                Err(e)
            }
        }
    }

    fn build(&mut self) -> Result<EncodedFrame, EncodeError> {
        let enc = &mut *self.encoder;
        enc.payload.push(kind::END_OF_FRAME);
        self.stats.messages += 1;
        let limits = enc.config.limits;
        let within = |what, size: usize, limit: u32| {
            if size as u64 > limit as u64 {
                return Err(EncodeError::ReceiverLimit {
                    what,
                    size: size as u64,
                    limit: limit as u64,
                });
            }
            Ok(())
        };
        within(
            "message count",
            self.stats.messages as usize,
            limits.max_messages,
        )?;
        within("payload bytes", enc.payload.len(), limits.max_payload_bytes)?;
        let payload_len =
            u32::try_from(enc.payload.len()).map_err(|_| EncodeError::FrameTooLarge)?;
        let mut out = vec![0u8; HEADER_LEN];
        let mut compression = enc.config.compression;
        if compression != Compression::None {
            let compressed = enc.compressor.compress_into(
                compression,
                enc.config.zstd_level,
                &enc.payload,
                &mut out,
            );
            if compressed.is_err() || out.len() - HEADER_LEN >= enc.payload.len() {
                out.truncate(HEADER_LEN);
                compression = Compression::None;
            }
        }
        if compression == Compression::None {
            out.extend_from_slice(&enc.payload);
        }
        within("frame bytes", out.len(), limits.max_frame_bytes)?;
        let compressed_len =
            u32::try_from(out.len() - HEADER_LEN).map_err(|_| EncodeError::FrameTooLarge)?;
        let (sequence, base_sequence) = if self.keyframe {
            (enc.sequence, enc.sequence)
        } else {
            (enc.sequence.wrapping_add(1), enc.sequence)
        };
        let mut header = FrameHeader {
            keyframe: self.keyframe,
            has_checksum: enc.config.checksum,
            compression,
            sequence,
            base_sequence,
            message_count: self.stats.messages,
            uncompressed_len: payload_len,
            compressed_len,
            checksum: 0,
        };
        let mut head = [0u8; HEADER_LEN];
        header.write(&mut head);
        if header.has_checksum {
            header.checksum = frame_checksum(&head, &out[HEADER_LEN..]);
            header.write(&mut head);
        }
        out[..HEADER_LEN].copy_from_slice(&head);
        enc.sequence = sequence;
        self.stats.payload_bytes = payload_len;
        self.stats.frame_bytes = out.len() as u32;
        Ok(EncodedFrame {
            bytes: Bytes::from(out),
            sequence,
            keyframe: self.keyframe,
            stats: self.stats,
        })
    }
}
