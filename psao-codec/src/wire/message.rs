//! Messages of a frame payload (spec/wire-format.md, "Messages"): parsing
//! into views that borrow the payload, and writing.
//!
//! Parsing here checks syntax only (lengths, varints, counts, masks,
//! definitions, finite floats). What depends on the mirror's state
//! (instances, capacities, compaction) is checked when the
//! [`Mirror`](crate::Mirror) applies a frame.

use glam::{UVec3, Vec3};

use crate::error::MessageError;
use crate::grid::{InstanceDef, MAX_BUCKET_CAPACITY, MAX_CELL_CAPACITY, OVERFLOW_FLAG};

/// Message type bytes.
pub mod kind {
    /// Ends the payload.
    pub const END_OF_FRAME: u8 = 0x00;
    /// Defines (or redefines, clearing it) an instance.
    pub const DEFINE_INSTANCE: u8 = 0x01;
    /// Removes an instance.
    pub const REMOVE_INSTANCE: u8 = 0x02;
    /// Sets an instance's local-to-world transform.
    pub const TRANSFORM: u8 = 0x03;
    /// Replaces whole hash buckets.
    pub const BUCKETS: u8 = 0x04;
    /// Replaces whole cells.
    pub const CELLS_FULL: u8 = 0x05;
    /// XORs words into cells.
    pub const CELLS_XOR: u8 = 0x06;
    /// Adds (mod 256) to the AO byte of allocated points.
    pub const CELLS_AO: u8 = 0x07;
    /// Clears cells to all-zero words.
    pub const CELLS_FREE: u8 = 0x08;
}

/// An array of `u32` stored as four byte planes: plane `b` holds byte `b`
/// (little-endian order) of every value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlanarU32<'a> {
    bytes: &'a [u8],
    len: usize,
}

impl<'a> PlanarU32<'a> {
    /// Number of values.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no values.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Value `i`; `i` must be below `len()`.
    #[inline]
    pub fn get(&self, i: usize) -> u32 {
        let n = self.len;
        u32::from_le_bytes([
            self.bytes[i],
            self.bytes[n + i],
            self.bytes[2 * n + i],
            self.bytes[3 * n + i],
        ])
    }

    /// The four planes.
    #[inline]
    pub fn planes(&self) -> [&'a [u8]; 4] {
        let n = self.len;
        [
            &self.bytes[..n],
            &self.bytes[n..2 * n],
            &self.bytes[2 * n..3 * n],
            &self.bytes[3 * n..4 * n],
        ]
    }
}

/// A strictly increasing list of indices coded as LEB128 varints: the first
/// value as it is, each next one as `index - previous - 1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexList<'a> {
    bytes: &'a [u8],
    len: usize,
}

impl<'a> IndexList<'a> {
    /// Number of indices.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The indices in order (already validated at parse time).
    pub fn iter(&self) -> IndexIter<'a> {
        IndexIter {
            reader: Reader::new(self.bytes),
            next: 0,
            left: self.len,
        }
    }
}

/// Iterator over an [`IndexList`].
#[derive(Clone, Debug)]
pub struct IndexIter<'a> {
    reader: Reader<'a>,
    next: u64,
    left: usize,
}

impl Iterator for IndexIter<'_> {
    type Item = u32;

    #[inline]
    fn next(&mut self) -> Option<u32> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        // Validated at parse time; a failure here cannot happen, but is
        // handled by ending the iteration rather than panicking.
        let d = self.reader.varint().ok()?;
        let v = self.next + d as u64;
        self.next = v + 1;
        Some(v as u32)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left, Some(self.left))
    }
}

/// The `Buckets` message: whole buckets replaced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BucketsMsg<'a> {
    /// Instance id.
    pub instance: u32,
    /// Bucket indices.
    pub buckets: IndexList<'a>,
    /// Occupied entries of each bucket (the rest become empty).
    pub counts: &'a [u8],
    /// Keys of all listed entries, bucket after bucket.
    pub keys: PlanarU32<'a>,
    /// Cell indices of all listed entries.
    pub cells: PlanarU32<'a>,
}

/// The three cell-update messages (`CellsFull`, `CellsXor`, `CellsAo`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellsMsg<'a> {
    /// Instance id.
    pub instance: u32,
    /// Cell indices.
    pub cells: IndexList<'a>,
    /// `CellsFull`: point count per cell; `CellsXor`/`CellsAo`: slot mask per cell.
    pub per_cell: &'a [u8],
    /// The payload bytes: planar words (Full, Xor) or AO deltas (Ao).
    pub data: &'a [u8],
}

impl<'a> CellsMsg<'a> {
    /// The words of a `CellsFull` or `CellsXor` message.
    pub fn words(&self) -> PlanarU32<'a> {
        PlanarU32 {
            bytes: self.data,
            len: self.data.len() / 4,
        }
    }
}

/// One decoded message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message<'a> {
    /// End of the payload.
    EndOfFrame,
    /// Define or redefine (clear) an instance.
    DefineInstance {
        /// Instance id.
        instance: u32,
        /// Its grid.
        def: InstanceDef,
    },
    /// Remove an instance.
    RemoveInstance {
        /// Instance id.
        instance: u32,
    },
    /// Instance-local to world transform.
    Transform {
        /// Instance id.
        instance: u32,
        /// Transform sequence: applied only if newer than the mirror's.
        transform_sequence: u32,
        /// Column-major 3x4 affine matrix: x axis, y axis, z axis, translation.
        matrix: [f32; 12],
    },
    /// Whole buckets.
    Buckets(BucketsMsg<'a>),
    /// Whole cells.
    CellsFull(CellsMsg<'a>),
    /// XOR deltas of cell words.
    CellsXor(CellsMsg<'a>),
    /// AO deltas.
    CellsAo(CellsMsg<'a>),
    /// Cells cleared to zero.
    CellsFree {
        /// Instance id.
        instance: u32,
        /// Cell indices.
        cells: IndexList<'a>,
    },
}

impl Message<'_> {
    /// The type byte of this message.
    pub fn kind(&self) -> u8 {
        match self {
            Message::EndOfFrame => kind::END_OF_FRAME,
            Message::DefineInstance { .. } => kind::DEFINE_INSTANCE,
            Message::RemoveInstance { .. } => kind::REMOVE_INSTANCE,
            Message::Transform { .. } => kind::TRANSFORM,
            Message::Buckets(_) => kind::BUCKETS,
            Message::CellsFull(_) => kind::CELLS_FULL,
            Message::CellsXor(_) => kind::CELLS_XOR,
            Message::CellsAo(_) => kind::CELLS_AO,
            Message::CellsFree { .. } => kind::CELLS_FREE,
        }
    }
}

/// A bounded little-endian cursor: every read checks the remaining length.
#[derive(Clone, Debug)]
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Reader { buf, pos: 0 }
    }

    pub(crate) fn pos(&self) -> usize {
        self.pos
    }

    pub(crate) fn byte_at(&self, i: usize) -> u8 {
        self.buf.get(i).copied().unwrap_or(0)
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.pos >= self.buf.len()
    }

    pub(crate) fn bytes(&mut self, n: usize) -> Result<&'a [u8], MessageError> {
        let end = self.pos.checked_add(n).ok_or(MessageError::Truncated)?;
        let s = self.buf.get(self.pos..end).ok_or(MessageError::Truncated)?;
        self.pos = end;
        Ok(s)
    }

    pub(crate) fn u8(&mut self) -> Result<u8, MessageError> {
        Ok(self.bytes(1)?[0])
    }

    pub(crate) fn u32(&mut self) -> Result<u32, MessageError> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    pub(crate) fn f32(&mut self) -> Result<f32, MessageError> {
        self.u32().map(f32::from_bits)
    }

    fn vec3(&mut self) -> Result<Vec3, MessageError> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }

    /// Minimal unsigned LEB128, at most 5 bytes, value below 2^32.
    #[inline]
    pub(crate) fn varint(&mut self) -> Result<u32, MessageError> {
        let mut v: u64 = 0;
        for i in 0..5 {
            let b = self.u8()?;
            v |= ((b & 0x7F) as u64) << (7 * i);
            if b & 0x80 == 0 {
                if (b == 0 && i > 0) || v > u32::MAX as u64 {
                    return Err(MessageError::Varint);
                }
                return Ok(v as u32);
            }
        }
        Err(MessageError::Varint)
    }

    fn index_list(&mut self, count: u32) -> Result<IndexList<'a>, MessageError> {
        let start = self.pos;
        let mut next: u64 = 0;
        for _ in 0..count {
            let v = next + self.varint()? as u64;
            if v > u32::MAX as u64 {
                return Err(MessageError::IndexOverflow);
            }
            next = v + 1;
        }
        Ok(IndexList {
            bytes: &self.buf[start..self.pos],
            len: count as usize,
        })
    }

    fn planar(&mut self, n: usize) -> Result<PlanarU32<'a>, MessageError> {
        let bytes = self.bytes(n.checked_mul(4).ok_or(MessageError::Truncated)?)?;
        Ok(PlanarU32 { bytes, len: n })
    }

    /// Reads a count whose items take at least one byte each, so that a
    /// count larger than what is left fails before anything relies on it.
    fn count(&mut self) -> Result<u32, MessageError> {
        let n = self.u32()?;
        if n as usize > self.buf.len() - self.pos {
            return Err(MessageError::Truncated);
        }
        Ok(n)
    }

    /// Parses one message starting at the type byte.
    pub(crate) fn message(&mut self) -> Result<Message<'a>, MessageError> {
        let t = self.u8()?;
        Ok(match t {
            kind::END_OF_FRAME => Message::EndOfFrame,
            kind::DEFINE_INSTANCE => {
                let instance = self.u32()?;
                let origin = self.vec3()?;
                let cell_size = self.vec3()?;
                let dims = UVec3::new(self.u32()?, self.u32()?, self.u32()?);
                let table_log2 = self.u8()?;
                let bucket_capacity = self.u8()?;
                let cell_capacity = self.u8()?;
                let format = self.u8()?;
                let cell_pool = self.u32()?;
                let radius = self.f32()?;
                let t_n = self.f32()?;
                let t_d = self.f32()?;
                let def = InstanceDef {
                    origin,
                    cell_size,
                    dims,
                    table_log2,
                    bucket_capacity,
                    cell_capacity,
                    cell_pool,
                    point_format: format & !OVERFLOW_FLAG,
                    overflow: format & OVERFLOW_FLAG != 0,
                    radius,
                    t_n,
                    t_d,
                };
                def.validate()?;
                Message::DefineInstance { instance, def }
            }
            kind::REMOVE_INSTANCE => Message::RemoveInstance {
                instance: self.u32()?,
            },
            kind::TRANSFORM => {
                let instance = self.u32()?;
                let transform_sequence = self.u32()?;
                let mut matrix = [0f32; 12];
                for m in &mut matrix {
                    *m = self.f32()?;
                }
                if !matrix.iter().all(|m| m.is_finite()) {
                    return Err(MessageError::NonFiniteTransform);
                }
                Message::Transform {
                    instance,
                    transform_sequence,
                    matrix,
                }
            }
            kind::BUCKETS => {
                let instance = self.u32()?;
                let n = self.count()?;
                let buckets = self.index_list(n)?;
                let counts = self.bytes(n as usize)?;
                let mut entries = 0usize;
                for &c in counts {
                    if c > MAX_BUCKET_CAPACITY {
                        return Err(MessageError::CountTooLarge(c));
                    }
                    entries = entries
                        .checked_add(c as usize)
                        .ok_or(MessageError::Truncated)?;
                }
                let keys = self.planar(entries)?;
                let cells = self.planar(entries)?;
                Message::Buckets(BucketsMsg {
                    instance,
                    buckets,
                    counts,
                    keys,
                    cells,
                })
            }
            kind::CELLS_FULL | kind::CELLS_XOR | kind::CELLS_AO => {
                let instance = self.u32()?;
                let n = self.count()?;
                let cells = self.index_list(n)?;
                let per_cell = self.bytes(n as usize)?;
                let mut points = 0usize;
                for &c in per_cell {
                    if c == 0 {
                        return Err(MessageError::ZeroMask);
                    }
                    let n = if t == kind::CELLS_FULL {
                        if c > MAX_CELL_CAPACITY {
                            return Err(MessageError::CountTooLarge(c));
                        }
                        c as usize
                    } else {
                        c.count_ones() as usize
                    };
                    points = points.checked_add(n).ok_or(MessageError::Truncated)?;
                }
                let width = if t == kind::CELLS_AO { 1 } else { 4 };
                let data = self.bytes(points.checked_mul(width).ok_or(MessageError::Truncated)?)?;
                let msg = CellsMsg {
                    instance,
                    cells,
                    per_cell,
                    data,
                };
                match t {
                    kind::CELLS_FULL => Message::CellsFull(msg),
                    kind::CELLS_XOR => Message::CellsXor(msg),
                    _ => Message::CellsAo(msg),
                }
            }
            kind::CELLS_FREE => {
                let instance = self.u32()?;
                let n = self.count()?;
                Message::CellsFree {
                    instance,
                    cells: self.index_list(n)?,
                }
            }
            other => return Err(MessageError::UnknownType(other)),
        })
    }
}

/// Appends messages to a payload buffer.
pub(crate) mod write {
    use bytes::BufMut;

    use super::kind;
    use crate::grid::InstanceDef;

    pub(crate) fn varint(out: &mut Vec<u8>, mut v: u32) {
        while v >= 0x80 {
            out.put_u8((v as u8) | 0x80);
            v >>= 7;
        }
        out.put_u8(v as u8);
    }

    /// Writes a strictly increasing index list.
    pub(crate) fn index_list(out: &mut Vec<u8>, indices: impl IntoIterator<Item = u32>) {
        let mut next = 0u32;
        for i in indices {
            debug_assert!(i >= next);
            varint(out, i - next);
            next = i.wrapping_add(1);
        }
    }

    /// Writes values as four byte planes.
    pub(crate) fn planar(out: &mut Vec<u8>, values: &[u32]) {
        for b in 0..4 {
            out.extend(values.iter().map(|v| (v >> (8 * b)) as u8));
        }
    }

    pub(crate) fn define(out: &mut Vec<u8>, instance: u32, d: &InstanceDef) {
        out.put_u8(kind::DEFINE_INSTANCE);
        out.put_u32_le(instance);
        for v in [d.origin, d.cell_size] {
            v.to_array().iter().for_each(|f| out.put_f32_le(*f));
        }
        d.dims.to_array().iter().for_each(|x| out.put_u32_le(*x));
        out.put_slice(&[
            d.table_log2,
            d.bucket_capacity,
            d.cell_capacity,
            d.format_byte(),
        ]);
        out.put_u32_le(d.cell_pool);
        out.put_f32_le(d.radius);
        out.put_f32_le(d.t_n);
        out.put_f32_le(d.t_d);
    }

    pub(crate) fn remove(out: &mut Vec<u8>, instance: u32) {
        out.put_u8(kind::REMOVE_INSTANCE);
        out.put_u32_le(instance);
    }

    pub(crate) fn transform(out: &mut Vec<u8>, instance: u32, seq: u32, m: &[f32; 12]) {
        out.put_u8(kind::TRANSFORM);
        out.put_u32_le(instance);
        out.put_u32_le(seq);
        m.iter().for_each(|f| out.put_f32_le(*f));
    }

    /// Type, instance and count: the start of every list message.
    pub(crate) fn list_head(out: &mut Vec<u8>, t: u8, instance: u32, count: usize) {
        out.put_u8(t);
        out.put_u32_le(instance);
        out.put_u32_le(count as u32);
    }
}
