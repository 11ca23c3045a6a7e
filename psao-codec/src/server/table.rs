//! The server's authoritative hash grid of one instance (paper 3.2).
//!
//! Points are addressed by caller-chosen dense ids. The table keeps buckets
//! and cells in exactly the layout a client [`Mirror`](crate::Mirror) holds,
//! keeps both compacted (occupied entries and allocated points first), and
//! records which buckets and cells changed since the last
//! [`GridTable::take_dirty`], with each dirty cell's words as last sent.
//! With [`InstanceDef::overflow`], a full cell goes on in an overflow chain
//! of up to 16 more cells (spec/wire-format.md 7.4), which the table keeps
//! compacted: every link but the last is full. Points that still do not fit
//! (full bucket, full chain, exhausted pool, outside the grid) are dropped
//! and counted, never silently.

use glam::Vec3;

use crate::error::{DefError, EncodeError};
use crate::grid::{BucketEntry, InstanceDef, MAX_CELL_CAPACITY};
use crate::wire::point::{POSITION_QUANTA, PointWord, quantize_ao};

/// Where a point id stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Placement {
    /// Not in the table (never set, or removed).
    Absent,
    /// Stored in `cell` at `slot`.
    Stored {
        /// Cell index.
        cell: u32,
        /// Slot in the cell.
        slot: u8,
    },
    /// Set, but dropped for the given reason; retried on its next update.
    Dropped(DropReason),
}

/// Why a point is not stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DropReason {
    /// Its position is outside the grid (or not finite).
    OutOfGrid,
    /// Its cell is new and its bucket is full (hash collisions).
    BucketFull,
    /// Its cell already holds `cell_capacity` points (with
    /// [`InstanceDef::overflow`]: in each of its 17 links, `17 *
    /// cell_capacity` in all).
    CellFull,
    /// Its cell is new and no free cell is left in the pool.
    PoolExhausted,
}

/// What the table holds now (`stored`, `cells`, `dropped`) and how many
/// drop events happened since creation (the other counters; a dropped point
/// is retried, and counted again, at each of its updates).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TableStats {
    /// Points stored now.
    pub stored: u32,
    /// Cells allocated now.
    pub cells: u32,
    /// Points set but not stored now (dropped for any reason).
    pub dropped: u32,
    /// Drops because the point was outside the grid.
    pub out_of_grid: u64,
    /// Drops because a bucket was full.
    pub bucket_overflow: u64,
    /// Drops because a cell was full.
    pub cell_overflow: u64,
    /// Drops because the cell pool was exhausted.
    pub pool_exhausted: u64,
}

/// When a point is worth sending again (the paper's thresholds).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thresholds {
    /// Position change, in quanta of the cell (the paper: 3).
    pub position_quanta: f32,
    /// Smallest cosine between old and new normal that is not an update (0.6).
    pub normal_cos: f32,
    /// AO change in 1/255 steps above which it is an update (8). A change
    /// to fully open (255) is an update whatever its size
    /// ([`SentPoint::changed`]).
    pub ao_steps: u8,
}

impl Default for Thresholds {
    fn default() -> Self {
        Thresholds {
            position_quanta: 3.0,
            normal_cos: 0.6,
            ao_steps: 8,
        }
    }
}

impl Thresholds {
    /// Whether AO quantized to `now` is an update over `held`, what
    /// clients hold (both in 1/255 steps): more than `ao_steps` away, or
    /// fully open (255) while clients hold less (see
    /// [`SentPoint::changed`]).
    pub fn ao_changed(&self, now: u8, held: u8) -> bool {
        now.abs_diff(held) > self.ao_steps || (now == u8::MAX && held != u8::MAX)
    }
}

/// What a client holds for one point, next to the point's new position
/// and normal ([`GridTable::sent`]): all a new AO value is compared with.
/// Plain data, so that a backend can compare where it traced (psao-gpu
/// uploads it as it is).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentPoint {
    /// The word the client holds, or [`PointWord::EMPTY`] when the point
    /// must be sent whatever its AO (not stored, or moving to another
    /// cell).
    pub word: PointWord,
    /// The new position inside the word's cell, in cell units (as
    /// [`PointWord::encode`] takes it; zero with an empty word).
    pub frac: Vec3,
    /// The new unit normal (zero when the given one has no direction).
    pub normal: Vec3,
    /// The cell holding the word (`u32::MAX` with an empty word).
    pub cell: u32,
}

impl SentPoint {
    /// The record of a point its clients do not hold (or that must be sent
    /// whatever its AO): an empty word, with the new unit normal.
    pub fn not_held(normal: Vec3) -> SentPoint {
        SentPoint {
            word: PointWord::EMPTY,
            frac: Vec3::ZERO,
            normal,
            cell: u32::MAX,
        }
    }

    /// Whether a point with this position, normal and AO `ao` is worth
    /// sending (the paper's thresholds): its word is empty, it moved by
    /// more than `position_quanta` quanta, its normal turned past
    /// `normal_cos`, or its AO changed by more than `ao_steps`; or, past
    /// the paper, its AO became fully open (255) while clients hold less.
    /// A trace comes out open only when none of the point's rays meets
    /// anything within the radius: where something passed and left, that
    /// is where the point's AO rests until something comes back, so the
    /// change is not noise that a later one undoes, and below the
    /// threshold it would leave up to `ao_steps` of darkness behind for
    /// good.
    pub fn changed(&self, ao: f32, thresholds: &Thresholds) -> bool {
        if !self.word.is_allocated() {
            return true;
        }
        // The distance against the threshold, squared (no square root, so
        // a device can do the same arithmetic).
        let q = thresholds.position_quanta;
        let d2 = ((self.frac - self.word.frac()) * POSITION_QUANTA as f32).length_squared();
        let moved = q < 0.0 || d2 > q * q;
        let turned = self.word.normal().dot(self.normal) < thresholds.normal_cos;
        let shaded = thresholds.ao_changed(quantize_ao(ao), self.word.fields().ao);
        moved || turned || shaded
    }
}

/// A changed cell: its index and its words as the client last saw them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirtyCell {
    /// Cell index.
    pub cell: u32,
    /// Words before the changes (only `cell_capacity` of them are used).
    pub old: [u32; MAX_CELL_CAPACITY as usize],
}

/// What changed in a table since the last [`GridTable::take_dirty`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DirtySet {
    /// Changed buckets, ascending.
    pub buckets: Vec<u32>,
    /// Changed cells, ascending by index.
    pub cells: Vec<DirtyCell>,
}

impl DirtySet {
    /// Whether nothing changed.
    pub fn is_empty(&self) -> bool {
        self.buckets.is_empty() && self.cells.is_empty()
    }
}

const ABSENT: u32 = u32::MAX;

/// Where a point is. Packed to 5 bytes (one per point of the server's
/// points: 8 with padding); its fields are read and written by value only
/// (a reference to a packed field does not compile).
#[derive(Clone, Copy, Debug)]
#[repr(C, packed)]
struct Loc {
    /// Cell index, [`ABSENT`], or `ABSENT - 1 - reason` for a dropped point.
    cell: u32,
    slot: u8,
}

impl Loc {
    fn placement(self) -> Placement {
        let (cell, slot) = (self.cell, self.slot);
        match cell {
            ABSENT => Placement::Absent,
            c if c >= ABSENT - 4 => Placement::Dropped(match ABSENT - 1 - c {
                0 => DropReason::OutOfGrid,
                1 => DropReason::BucketFull,
                2 => DropReason::CellFull,
                _ => DropReason::PoolExhausted,
            }),
            cell => Placement::Stored { cell, slot },
        }
    }

    fn dropped(reason: DropReason) -> Loc {
        let r = match reason {
            DropReason::OutOfGrid => 0,
            DropReason::BucketFull => 1,
            DropReason::CellFull => 2,
            DropReason::PoolExhausted => 3,
        };
        Loc {
            cell: ABSENT - 1 - r,
            slot: 0,
        }
    }
}

/// The authoritative hash grid of one instance.
#[derive(Clone, Debug)]
pub struct GridTable {
    id: u32,
    def: InstanceDef,
    buckets: Vec<BucketEntry>,
    bucket_len: Vec<u8>,
    words: Vec<u32>,
    cell_len: Vec<u8>,
    /// The key each cell is filed under in its bucket (a link key for a
    /// link of an overflow chain).
    cell_key: Vec<u32>,
    /// Which link of its grid cell's chain each cell is (0: the cell's
    /// own key).
    cell_link: Vec<u8>,
    slot_point: Vec<u32>,
    free: Vec<u32>,
    points: Vec<Loc>,
    max_points: u32,
    bucket_dirty: Vec<bool>,
    dirty_buckets: Vec<u32>,
    cell_dirty: Vec<bool>,
    dirty_cells: Vec<DirtyCell>,
    stats: TableStats,
}

impl GridTable {
    /// An empty table for instance `id` whose points have dense ids below
    /// `max_points` (the table keeps 8 bytes per id, so a wrong id cannot
    /// make it allocate without bound).
    pub fn new(id: u32, def: InstanceDef, max_points: u32) -> Result<GridTable, EncodeError> {
        def.validate()?;
        // The top five cell indices mark absent and dropped points.
        if def.cell_pool >= ABSENT - 5 {
            return Err(EncodeError::Def(DefError::CellPool));
        }
        let cells = def.cell_pool as usize;
        Ok(GridTable {
            id,
            def,
            buckets: vec![BucketEntry::EMPTY; def.bucket_entries()],
            bucket_len: vec![0; def.table_size() as usize],
            words: vec![0; def.cell_words()],
            cell_len: vec![0; cells],
            cell_key: vec![0; cells],
            cell_link: vec![0; cells],
            slot_point: vec![ABSENT; def.cell_words()],
            free: (0..def.cell_pool).rev().collect(),
            points: Vec::new(),
            max_points,
            bucket_dirty: vec![false; def.table_size() as usize],
            dirty_buckets: Vec::new(),
            cell_dirty: vec![false; cells],
            dirty_cells: Vec::new(),
            stats: TableStats::default(),
        })
    }

    /// The instance id.
    pub fn id(&self) -> u32 {
        self.id
    }

    /// The grid definition.
    pub fn def(&self) -> &InstanceDef {
        &self.def
    }

    /// Bucket entries, in the mirror's layout.
    pub fn buckets(&self) -> &[BucketEntry] {
        &self.buckets
    }

    /// Point words, in the mirror's layout.
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// Occupied entries of a bucket.
    pub fn bucket(&self, bucket: u32) -> &[BucketEntry] {
        let cap = self.def.bucket_capacity as usize;
        let start = bucket as usize * cap;
        &self.buckets[start..start + self.bucket_len[bucket as usize] as usize]
    }

    /// All words of a cell (allocated first, then zeros).
    pub fn cell(&self, cell: u32) -> &[u32] {
        let cap = self.def.cell_capacity as usize;
        &self.words[cell as usize * cap..(cell as usize + 1) * cap]
    }

    /// Number of allocated points in a cell.
    pub fn cell_len(&self, cell: u32) -> u8 {
        self.cell_len[cell as usize]
    }

    /// Bytes the table holds (allocated capacity of its arrays): what a
    /// server pays per instance for its grid, its point locations and its
    /// dirty set.
    pub fn memory_bytes(&self) -> u64 {
        use std::mem::size_of;
        let bytes = |len: usize, size: usize| (len * size) as u64;
        bytes(self.buckets.capacity(), size_of::<BucketEntry>())
            + bytes(self.bucket_len.capacity(), 1)
            + bytes(self.words.capacity(), 4)
            + bytes(self.cell_len.capacity(), 1)
            + bytes(self.cell_key.capacity(), 4)
            + bytes(self.cell_link.capacity(), 1)
            + bytes(self.slot_point.capacity(), 4)
            + bytes(self.free.capacity(), 4)
            + bytes(self.points.capacity(), size_of::<Loc>())
            + bytes(self.bucket_dirty.capacity(), 1)
            + bytes(self.dirty_buckets.capacity(), 4)
            + bytes(self.cell_dirty.capacity(), 1)
            + bytes(self.dirty_cells.capacity(), size_of::<DirtyCell>())
    }

    /// Releases spare capacity: after a bulk load (the first trace sets
    /// every point), the free-cell list and the point records keep room
    /// they no longer need. The table's content does not change.
    pub fn shrink_to_fit(&mut self) {
        self.free.shrink_to_fit();
        self.points.shrink_to_fit();
        self.dirty_buckets.shrink_to_fit();
        self.dirty_cells.shrink_to_fit();
    }

    /// Counters.
    pub fn stats(&self) -> TableStats {
        self.stats
    }

    /// Where a point stands.
    pub fn placement(&self, id: u32) -> Placement {
        self.points
            .get(id as usize)
            .map_or(Placement::Absent, |l| l.placement())
    }

    /// Whether changes are waiting for [`take_dirty`](Self::take_dirty).
    pub fn has_pending(&self) -> bool {
        !self.dirty_buckets.is_empty() || !self.dirty_cells.is_empty()
    }

    /// Takes the set of buckets and cells changed since the last call.
    pub fn take_dirty(&mut self) -> DirtySet {
        let mut buckets = std::mem::take(&mut self.dirty_buckets);
        let mut cells = std::mem::take(&mut self.dirty_cells);
        for &b in &buckets {
            self.bucket_dirty[b as usize] = false;
        }
        for c in &cells {
            self.cell_dirty[c.cell as usize] = false;
        }
        buckets.sort_unstable();
        cells.sort_unstable_by_key(|c| c.cell);
        DirtySet { buckets, cells }
    }

    /// Sets a point (inserting, moving or updating it). `local` is its
    /// instance-local position, `normal` need not be normalized, `ao` is in
    /// `[0, 1]`. Returns where it ended up.
    pub fn set_point(
        &mut self,
        id: u32,
        local: Vec3,
        normal: Vec3,
        ao: f32,
    ) -> Result<Placement, EncodeError> {
        if id >= self.max_points {
            return Err(EncodeError::PointId {
                id,
                limit: self.max_points,
            });
        }
        let was_dropped = matches!(self.placement(id), Placement::Dropped(_));
        let placement = self.place(id, local, normal, ao);
        let is_dropped = matches!(placement, Placement::Dropped(_));
        match (was_dropped, is_dropped) {
            (false, true) => self.stats.dropped += 1,
            (true, false) => self.stats.dropped -= 1,
            _ => {}
        }
        Ok(placement)
    }

    fn place(&mut self, id: u32, local: Vec3, normal: Vec3, ao: f32) -> Placement {
        if self.points.len() <= id as usize {
            self.points.resize(
                id as usize + 1,
                Loc {
                    cell: ABSENT,
                    slot: 0,
                },
            );
        }
        let Some(cell_pos) = self.def.cell_of(local) else {
            self.unlink(id);
            self.stats.out_of_grid += 1;
            self.points[id as usize] = Loc::dropped(DropReason::OutOfGrid);
            return self.placement(id);
        };
        let frac = (local - self.def.cell_min(cell_pos)) / self.def.cell_size;
        let word = PointWord::encode(frac, normal, ao).0;
        let key = self.def.key(cell_pos);
        if let Placement::Stored { cell, slot } = self.placement(id)
            && self.grid_key(cell) == key
        {
            let i = cell as usize * self.def.cell_capacity as usize + slot as usize;
            if self.words[i] != word {
                self.touch_cell(cell);
                self.words[i] = word;
            }
            return self.placement(id);
        }
        self.unlink(id);
        let loc = self.insert(id, key, word);
        self.points[id as usize] = loc;
        loc.placement()
    }

    /// What the client holds for point `id` against which a new
    /// `local` position and `normal` (and then AO) are compared: the word
    /// the client holds where the point stays in the same cell, otherwise
    /// [`PointWord::EMPTY`] (it must be sent whatever its AO).
    pub fn sent(&self, id: u32, local: Vec3, normal: Vec3) -> SentPoint {
        let normal = normal.normalize_or_zero();
        if let Placement::Stored { cell, slot } = self.placement(id)
            && let Some(cell_pos) = self.def.cell_of(local)
            && self.def.key(cell_pos) == self.grid_key(cell)
        {
            let cap = self.def.cell_capacity as usize;
            return SentPoint {
                word: PointWord(self.words[cell as usize * cap + slot as usize]),
                frac: (local - self.def.cell_min(cell_pos)) / self.def.cell_size,
                normal,
                cell,
            };
        }
        SentPoint::not_held(normal)
    }

    /// Sets a point only if it differs from what the client holds by more
    /// than the thresholds (or moved to another cell, or is not stored):
    /// [`GridTable::sent`] then [`SentPoint::changed`]. Returns whether it
    /// was set.
    pub fn update_point(
        &mut self,
        id: u32,
        local: Vec3,
        normal: Vec3,
        ao: f32,
        thresholds: &Thresholds,
    ) -> Result<bool, EncodeError> {
        if !self.sent(id, local, normal).changed(ao, thresholds) {
            return Ok(false);
        }
        self.set_point(id, local, normal, ao)?;
        Ok(true)
    }

    /// Removes a point. Returns whether it was stored.
    pub fn remove_point(&mut self, id: u32) -> bool {
        let stored = matches!(self.placement(id), Placement::Stored { .. });
        if matches!(self.placement(id), Placement::Dropped(_)) {
            self.stats.dropped -= 1;
        }
        self.unlink(id);
        if let Some(l) = self.points.get_mut(id as usize) {
            l.cell = ABSENT;
        }
        stored
    }

    fn touch_cell(&mut self, cell: u32) {
        if !self.cell_dirty[cell as usize] {
            self.cell_dirty[cell as usize] = true;
            let mut old = [0u32; MAX_CELL_CAPACITY as usize];
            let words = self.cell(cell);
            old[..words.len()].copy_from_slice(words);
            self.dirty_cells.push(DirtyCell { cell, old });
        }
    }

    fn touch_bucket(&mut self, bucket: u32) {
        if !self.bucket_dirty[bucket as usize] {
            self.bucket_dirty[bucket as usize] = true;
            self.dirty_buckets.push(bucket);
        }
    }

    /// The key of the grid cell a pool cell holds points of (eq. 1), which
    /// for a link of an overflow chain is not the key it is filed under.
    fn grid_key(&self, cell: u32) -> u32 {
        let link = self.cell_link[cell as usize] as u32;
        self.cell_key[cell as usize] - link * self.def.dims.x
    }

    /// The cell filed under `key` in `bucket`, if any.
    fn find(&self, key: u32, bucket: u32) -> Option<u32> {
        let cap = self.def.bucket_capacity as usize;
        let start = bucket as usize * cap;
        let len = self.bucket_len[bucket as usize] as usize;
        self.buckets[start..start + len]
            .iter()
            .find(|e| e.key == key)
            .map(|e| e.cell)
    }

    /// Files a free cell under `key` in `bucket` as link `link` of its
    /// chain.
    fn new_cell(&mut self, key: u32, bucket: u32, link: u8) -> Result<u32, Loc> {
        let cap = self.def.bucket_capacity as usize;
        let len = self.bucket_len[bucket as usize] as usize;
        if len == cap {
            self.stats.bucket_overflow += 1;
            return Err(Loc::dropped(DropReason::BucketFull));
        }
        let Some(cell) = self.free.pop() else {
            self.stats.pool_exhausted += 1;
            return Err(Loc::dropped(DropReason::PoolExhausted));
        };
        self.touch_bucket(bucket);
        self.buckets[bucket as usize * cap + len] = BucketEntry { key, cell };
        self.bucket_len[bucket as usize] += 1;
        self.cell_key[cell as usize] = key;
        self.cell_link[cell as usize] = link;
        self.stats.cells += 1;
        Ok(cell)
    }

    /// Stores a point in the first link of its cell's chain with room
    /// (the last one, or a new one after it), since every link but the
    /// last is full.
    fn insert(&mut self, id: u32, key: u32, word: u32) -> Loc {
        for link in 0..=self.def.max_links() {
            let link_key = self.def.link_key(key, link);
            let bucket = self.def.bucket_of_link(key, link);
            let cell = match self.find(link_key, bucket) {
                Some(cell) => cell,
                None => match self.new_cell(link_key, bucket, link) {
                    Ok(cell) => cell,
                    Err(dropped) => return dropped,
                },
            };
            let n = self.cell_len[cell as usize];
            if n == self.def.cell_capacity {
                continue;
            }
            self.touch_cell(cell);
            let i = cell as usize * self.def.cell_capacity as usize + n as usize;
            self.words[i] = word;
            self.slot_point[i] = id;
            self.cell_len[cell as usize] = n + 1;
            self.stats.stored += 1;
            return Loc { cell, slot: n };
        }
        self.stats.cell_overflow += 1;
        Loc::dropped(DropReason::CellFull)
    }

    /// The last link of the chain `cell` belongs to (`cell` itself when it
    /// is the last, or chains are off).
    fn last_link(&self, cell: u32) -> u32 {
        let key = self.grid_key(cell);
        let mut last = cell;
        let mut link = self.cell_link[cell as usize];
        while link < self.def.max_links() && self.cell_len[last as usize] == self.def.cell_capacity
        {
            link += 1;
            match self.find(
                self.def.link_key(key, link),
                self.def.bucket_of_link(key, link),
            ) {
                Some(next) => last = next,
                None => break,
            }
        }
        last
    }

    /// Takes a stored point out of its cell, keeping the cell and its chain
    /// compacted (the chain's last point fills the hole) and freeing the
    /// last link when it empties. The caller sets the point's new `Loc`.
    fn unlink(&mut self, id: u32) {
        let Some(Placement::Stored { cell, slot }) =
            self.points.get(id as usize).map(|l| l.placement())
        else {
            return;
        };
        let last_cell = self.last_link(cell);
        self.touch_cell(cell);
        self.touch_cell(last_cell);
        let cap = self.def.cell_capacity as usize;
        let hole = cell as usize * cap + slot as usize;
        let last = self.cell_len[last_cell as usize] as usize - 1;
        let tail = last_cell as usize * cap + last;
        if tail != hole {
            self.words[hole] = self.words[tail];
            let moved = self.slot_point[tail];
            self.slot_point[hole] = moved;
            self.points[moved as usize] = Loc { cell, slot };
        }
        self.words[tail] = 0;
        self.slot_point[tail] = ABSENT;
        self.cell_len[last_cell as usize] = last as u8;
        self.points[id as usize].cell = ABSENT;
        self.stats.stored -= 1;
        if last == 0 {
            self.free_cell(last_cell);
        }
    }

    fn free_cell(&mut self, cell: u32) {
        let key = self.cell_key[cell as usize];
        let bucket = self
            .def
            .bucket_of_link(self.grid_key(cell), self.cell_link[cell as usize]);
        let cap = self.def.bucket_capacity as usize;
        let start = bucket as usize * cap;
        let len = self.bucket_len[bucket as usize] as usize;
        if let Some(pos) = self.buckets[start..start + len]
            .iter()
            .position(|e| e.key == key)
        {
            self.touch_bucket(bucket);
            self.buckets
                .copy_within(start + pos + 1..start + len, start + pos);
            self.buckets[start + len - 1] = BucketEntry::EMPTY;
            self.bucket_len[bucket as usize] -= 1;
        }
        self.free.push(cell);
        self.stats.cells -= 1;
    }
}
