//! Per-instance virtual grid: its definition, the cell key of eq. 1 and the
//! bucket a key hashes to (spec/wire-format.md, "Grid and cell key").

use glam::{UVec3, Vec3};

use crate::error::DefError;

/// Largest number of entries in a hash bucket.
pub const MAX_BUCKET_CAPACITY: u8 = 16;
/// Largest number of point slots in a cell (one mask byte per cell).
pub const MAX_CELL_CAPACITY: u8 = 8;
/// Largest `table_log2`: a table holds at most 2^31 buckets.
pub const MAX_TABLE_LOG2: u8 = 31;
/// The key of an empty bucket entry; never a valid cell key.
pub const EMPTY_KEY: u32 = u32::MAX;
/// Point format 0: the packed 32-bit word, in the instance's local space.
pub const POINT_FORMAT_PACKED32: u8 = 0;
/// Point format 1: the same word, in the bind space of a deforming mesh
/// (spec/wire-format.md 6.1): a client looks a pixel up by the bind-space
/// position and normal of the surface it shows, not through the
/// instance's transform.
pub const POINT_FORMAT_BIND32: u8 = 1;

/// Bit 7 of `DefineInstance`'s point format byte: the instance's full cells
/// continue in overflow chains (spec/wire-format.md 7.4).
pub const OVERFLOW_FLAG: u8 = 0x80;
/// Links a cell's overflow chain has beyond the cell itself: link `j`
/// (`1..=16`) of the cell with key `k` has key `k + j * Dx`, so a cell holds
/// at most `17 * cell_capacity` points.
pub const MAX_OVERFLOW_LINKS: u8 = 16;

/// The odd multiplier that spreads a cell's links over the table: link `j`
/// of the cell with key `k` lives in bucket `(k + j * LINK_HASH) mod T`
/// (spec/wire-format.md 7.4), which differs for every `j < T` whatever
/// the grid's dims.
pub const LINK_HASH: u32 = 0x9E37_79B9;

/// One hash bucket entry as laid out in memory: `(cell key, cell index)`,
/// both `u32::MAX` when empty. `#[repr(C)]`, 8 bytes, so an array of them
/// can be uploaded to a GPU as it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(C)]
pub struct BucketEntry {
    /// Cell key (eq. 1), or [`EMPTY_KEY`].
    pub key: u32,
    /// Index of the cell in the cell pool, or `u32::MAX` when empty.
    pub cell: u32,
}

impl BucketEntry {
    /// The empty entry.
    pub const EMPTY: BucketEntry = BucketEntry {
        key: EMPTY_KEY,
        cell: u32::MAX,
    };

    /// Whether the entry is empty.
    pub fn is_empty(self) -> bool {
        self.key == EMPTY_KEY
    }
}

/// Everything a client needs to know about an instance's grid: the body of
/// the `DefineInstance` message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstanceDef {
    /// Instance-local position of the grid's minimum corner.
    pub origin: Vec3,
    /// Size of a cell along each local axis (positive, finite).
    pub cell_size: Vec3,
    /// Number of cells along each axis, each at least 1, with
    /// `31 * dx * dy * dz <= 2^32 - 1` so every key fits 32 bits.
    pub dims: UVec3,
    /// The hash table has `2^table_log2` buckets, with
    /// `2^table_log2 * bucket_capacity <= 2^32 - 1`.
    pub table_log2: u8,
    /// Entries per bucket, `1..=16` (the paper: 8).
    pub bucket_capacity: u8,
    /// Point slots per cell, `1..=8` (the paper: 7).
    pub cell_capacity: u8,
    /// Number of cells in the cell pool; cell indices are `< cell_pool`, and
    /// `cell_pool * cell_capacity <= 2^32 - 1`.
    pub cell_pool: u32,
    /// Point format: [`POINT_FORMAT_PACKED32`] or [`POINT_FORMAT_BIND32`].
    pub point_format: u8,
    /// Whether a full cell continues in an overflow chain of up to
    /// [`MAX_OVERFLOW_LINKS`] more cells (spec/wire-format.md 7.4), sent as
    /// bit 7 ([`OVERFLOW_FLAG`]) of the point format byte.
    pub overflow: bool,
    /// Interpolation radius r of eq. 2, in local units (positive, finite).
    pub radius: f32,
    /// Normal threshold T_n of eq. 3, in `[-1, 1]`.
    pub t_n: f32,
    /// Direction threshold T_d of eq. 3, in `[0, 1]`.
    pub t_d: f32,
}

impl InstanceDef {
    /// Whether the points are in bind space (point format 1), looked up by
    /// a surface's bind-space position and normal.
    pub fn bind_space(&self) -> bool {
        self.point_format == POINT_FORMAT_BIND32
    }

    /// Byte 44 of `DefineInstance`: the point format in bits 0-6 and
    /// [`OVERFLOW_FLAG`] in bit 7.
    pub fn format_byte(&self) -> u8 {
        self.point_format | if self.overflow { OVERFLOW_FLAG } else { 0 }
    }

    /// Links a cell's chain may have beyond the cell itself:
    /// [`MAX_OVERFLOW_LINKS`] with [`overflow`](Self::overflow), else 0.
    pub fn max_links(&self) -> u8 {
        if self.overflow { MAX_OVERFLOW_LINKS } else { 0 }
    }

    /// Number of buckets.
    pub fn table_size(&self) -> u32 {
        1u32 << self.table_log2
    }

    /// Number of bucket entries (`table_size * bucket_capacity`).
    pub fn bucket_entries(&self) -> usize {
        (self.table_size() as usize) * self.bucket_capacity as usize
    }

    /// Number of point words in the cell pool (`cell_pool * cell_capacity`).
    pub fn cell_words(&self) -> usize {
        self.cell_pool as usize * self.cell_capacity as usize
    }

    /// Bytes a mirror of this instance occupies (bucket entries + words).
    pub fn mirror_bytes(&self) -> usize {
        self.bucket_entries() * std::mem::size_of::<BucketEntry>() + self.cell_words() * 4
    }

    /// Checks every rule of the spec that does not depend on receiver
    /// limits.
    pub fn validate(&self) -> Result<(), DefError> {
        let finite = self.origin.is_finite()
            && self.cell_size.is_finite()
            && self.radius.is_finite()
            && self.t_n.is_finite()
            && self.t_d.is_finite();
        if !finite {
            return Err(DefError::NonFinite);
        }
        if self.cell_size.min_element() <= 0.0 {
            return Err(DefError::CellSize);
        }
        if self.dims.min_element() == 0 || !key_fits(self.dims) {
            return Err(DefError::Dims);
        }
        // Entry and word indices must fit u32 (exact arithmetic: a
        // hostile `table_log2` must not overflow the product).
        let entries = (1u128 << self.table_log2.min(63)) * self.bucket_capacity as u128;
        if self.table_log2 > MAX_TABLE_LOG2 || entries > u32::MAX as u128 {
            return Err(DefError::TableSize);
        }
        if !(1..=MAX_BUCKET_CAPACITY).contains(&self.bucket_capacity) {
            return Err(DefError::BucketCapacity);
        }
        if !(1..=MAX_CELL_CAPACITY).contains(&self.cell_capacity) {
            return Err(DefError::CellCapacity);
        }
        let words = self.cell_pool as u64 * self.cell_capacity as u64;
        if self.cell_pool == 0 || words > u32::MAX as u64 {
            return Err(DefError::CellPool);
        }
        if !matches!(
            self.point_format,
            POINT_FORMAT_PACKED32 | POINT_FORMAT_BIND32
        ) {
            return Err(DefError::PointFormat);
        }
        if self.radius <= 0.0
            || !(-1.0..=1.0).contains(&self.t_n)
            || !(0.0..=1.0).contains(&self.t_d)
        {
            return Err(DefError::Reconstruction);
        }
        Ok(())
    }

    /// Cell coordinates containing a local position, or `None` outside the
    /// grid (or for a non-finite position).
    pub fn cell_of(&self, local: Vec3) -> Option<UVec3> {
        let g = (local - self.origin) / self.cell_size;
        if !g.is_finite() || g.min_element() < 0.0 {
            return None;
        }
        let c = g.floor();
        let dims = self.dims.as_vec3();
        if c.x >= dims.x || c.y >= dims.y || c.z >= dims.z {
            return None;
        }
        Some(c.as_uvec3())
    }

    /// Local position of a cell's minimum corner.
    pub fn cell_min(&self, cell: UVec3) -> Vec3 {
        self.origin + cell.as_vec3() * self.cell_size
    }

    /// The cell key of eq. 1: `x + y*Dx*17 + z*Dx*Dy*31`. `cell` must lie
    /// inside the grid; then the key is unique to the cell and below
    /// `2^32 - 1`.
    pub fn key(&self, cell: UVec3) -> u32 {
        let (dx, dy) = (self.dims.x as u64, self.dims.y as u64);
        let k = cell.x as u64 + cell.y as u64 * dx * 17 + cell.z as u64 * dx * dy * 31;
        debug_assert!(k < EMPTY_KEY as u64);
        k as u32
    }

    /// The cell a key names, or `None` if no cell of this grid has that key
    /// (a link key of an overflow chain names no cell: see
    /// [`link_of_key`](Self::link_of_key)).
    pub fn cell_of_key(&self, key: u32) -> Option<UVec3> {
        match self.any_link_of_key(key)? {
            (cell, 0) => Some(cell),
            _ => None,
        }
    }

    /// The cell and the link of its overflow chain that a key names (link 0
    /// is the cell's own key), or `None` if it names none. Without
    /// [`overflow`](Self::overflow) only link 0 keys are valid
    /// (spec/wire-format.md 7.4).
    pub fn link_of_key(&self, key: u32) -> Option<(UVec3, u8)> {
        let (cell, link) = self.any_link_of_key(key)?;
        (link == 0 || self.overflow).then_some((cell, link))
    }

    fn any_link_of_key(&self, key: u32) -> Option<(UVec3, u8)> {
        let (dx, dy, dz) = (self.dims.x as u64, self.dims.y as u64, self.dims.z as u64);
        let k = key as u64;
        let x = k % dx;
        let rest = k / dx;
        let layer = 31 * dy;
        let z = rest / layer;
        let r = rest % layer;
        if r / 17 >= dy || z >= dz {
            return None;
        }
        let cell = UVec3::new(x as u32, (r / 17) as u32, z as u32);
        Some((cell, (r % 17) as u8))
    }

    /// The key of link `link` (`0..=16`) of the overflow chain of the cell
    /// with key `key`: `key + link * Dx`. `key` must be a cell's own key;
    /// the result is then unique to that link and below `2^32 - 1`.
    pub fn link_key(&self, key: u32, link: u8) -> u32 {
        debug_assert!(link <= MAX_OVERFLOW_LINKS);
        let k = key as u64 + link as u64 * self.dims.x as u64;
        debug_assert!(k < EMPTY_KEY as u64);
        k as u32
    }

    /// The bucket link `link` of the chain of the cell with key
    /// `cell_key` lives in: `(cell_key + link * LINK_HASH) mod T`, which
    /// for link 0 is `cell_key mod T` (spec/wire-format.md 7.4).
    pub fn bucket_of_link(&self, cell_key: u32, link: u8) -> u32 {
        cell_key.wrapping_add((link as u32).wrapping_mul(LINK_HASH)) & (self.table_size() - 1)
    }

    /// The bucket a key lives in: `key mod T` for a cell's own key (and a
    /// key that names nothing), and for a link key of an instance with
    /// [`overflow`](Self::overflow) the bucket of
    /// [`bucket_of_link`](Self::bucket_of_link).
    pub fn bucket_of_key(&self, key: u32) -> u32 {
        if self.overflow
            && let Some((cell, link)) = self.link_of_key(key)
            && link > 0
        {
            return self.bucket_of_link(self.key(cell), link);
        }
        key & (self.table_size() - 1)
    }
}

/// Whether `31 * dx * dy * dz <= 2^32 - 1` (so keys fit 32 bits and never
/// equal [`EMPTY_KEY`]).
pub fn key_fits(dims: UVec3) -> bool {
    let p = 31u128 * dims.x as u128 * dims.y as u128 * dims.z as u128;
    p <= u32::MAX as u128
}
