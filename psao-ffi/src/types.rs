//! Plain C structs passed by value or pointer: limits, instance
//! definitions, transforms, events, changes, placements and statistics.
//! Inputs use `uint8_t` flags (0 or 1), never C `bool` or enums, so no bit
//! pattern a C caller writes can be invalid on the Rust side.

use glam::{UVec3, Vec3};
use psao_codec::{InstanceDef, Limits, Thresholds, Transform};

use crate::boundary::flag;
use crate::result::Failure;

/// What a decoder accepts before any length field can drive an allocation
/// (spec/wire-format.md, "Limits"). `psao_limits_default` gives the spec's
/// defaults.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_limits {
    /// Largest frame (header and payload as sent), bytes.
    pub max_frame_bytes: u32,
    /// Largest uncompressed payload, bytes.
    pub max_payload_bytes: u32,
    /// Most messages in one frame, EndOfFrame included.
    pub max_messages: u32,
    /// Most instances a mirror holds at once.
    pub max_instances: u32,
    /// Largest cell pool of an instance.
    pub max_cell_pool: u32,
    /// Largest `table_log2` of an instance.
    pub max_table_log2: u8,
    /// Largest total of bucket-entry and word bytes over all instances.
    pub max_mirror_bytes: u64,
}

impl From<Limits> for psao_limits {
    fn from(l: Limits) -> psao_limits {
        psao_limits {
            max_frame_bytes: l.max_frame_bytes,
            max_payload_bytes: l.max_payload_bytes,
            max_messages: l.max_messages,
            max_instances: l.max_instances,
            max_cell_pool: l.max_cell_pool,
            max_table_log2: l.max_table_log2,
            max_mirror_bytes: l.max_mirror_bytes,
        }
    }
}

impl From<psao_limits> for Limits {
    fn from(l: psao_limits) -> Limits {
        Limits {
            max_frame_bytes: l.max_frame_bytes,
            max_payload_bytes: l.max_payload_bytes,
            max_messages: l.max_messages,
            max_instances: l.max_instances,
            max_table_log2: l.max_table_log2,
            max_cell_pool: l.max_cell_pool,
            max_mirror_bytes: l.max_mirror_bytes,
        }
    }
}

/// An instance's hash grid and reconstruction parameters (the fields of
/// DefineInstance, spec/wire-format.md 5.1).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(non_camel_case_types)]
pub struct psao_instance_def {
    /// Grid origin in instance-local (or bind) space.
    pub origin: [f32; 3],
    /// Cell edge lengths.
    pub cell_size: [f32; 3],
    /// Cells per axis.
    pub dims: [u32; 3],
    /// log2 of the number of buckets.
    pub table_log2: u8,
    /// Entries per bucket (1 to 16).
    pub bucket_capacity: u8,
    /// Point slots per cell (1 to 8).
    pub cell_capacity: u8,
    /// Point format: 0 local space, 1 bind space.
    pub point_format: u8,
    /// 1 when cells may have overflow chains, else 0.
    pub overflow: u8,
    /// Cells in the pool.
    pub cell_pool: u32,
    /// Reconstruction radius r.
    pub radius: f32,
    /// Normal threshold T_n.
    pub t_n: f32,
    /// Distance threshold T_d.
    pub t_d: f32,
}

impl From<&InstanceDef> for psao_instance_def {
    fn from(d: &InstanceDef) -> psao_instance_def {
        psao_instance_def {
            origin: d.origin.to_array(),
            cell_size: d.cell_size.to_array(),
            dims: d.dims.to_array(),
            table_log2: d.table_log2,
            bucket_capacity: d.bucket_capacity,
            cell_capacity: d.cell_capacity,
            point_format: d.point_format,
            overflow: d.overflow as u8,
            cell_pool: d.cell_pool,
            radius: d.radius,
            t_n: d.t_n,
            t_d: d.t_d,
        }
    }
}

impl psao_instance_def {
    /// The codec's definition; only the `overflow` flag is checked here
    /// (the rest by the codec, as for a definition from the wire).
    pub(crate) fn to_def(self) -> Result<InstanceDef, Failure> {
        Ok(InstanceDef {
            origin: Vec3::from_array(self.origin),
            cell_size: Vec3::from_array(self.cell_size),
            dims: UVec3::from_array(self.dims),
            table_log2: self.table_log2,
            bucket_capacity: self.bucket_capacity,
            cell_capacity: self.cell_capacity,
            cell_pool: self.cell_pool,
            point_format: self.point_format,
            overflow: flag(self.overflow, "def.overflow")?,
            radius: self.radius,
            t_n: self.t_n,
            t_d: self.t_d,
        })
    }
}

/// An instance's local-to-world transform: a column-major 3x4 matrix
/// (columns x, y, z, translation) and the transform sequence that orders
/// transforms of one instance.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(non_camel_case_types)]
pub struct psao_transform {
    /// Newer transforms replace older ones (serial-number order).
    pub sequence: u32,
    /// Column-major 3x4 local-to-world matrix.
    pub matrix: [f32; 12],
}

impl From<Transform> for psao_transform {
    fn from(t: Transform) -> psao_transform {
        psao_transform {
            sequence: t.sequence,
            matrix: t.matrix,
        }
    }
}

/// What a decoder did with a frame.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_event_kind {
    /// The frame was applied: the mirror is at `sequence`. Upload the
    /// changed ranges (`psao_decoder_changes`).
    PSAO_EVENT_APPLIED = 1,
    /// The frame is not newer than the mirror: ignored, nothing to do.
    PSAO_EVENT_STALE = 2,
    /// The frame does not apply to the mirror (a frame was missed, or no
    /// keyframe yet): keep drawing the mirror and ask for a keyframe.
    PSAO_EVENT_NEED_KEYFRAME = 3,
}

/// The event of one received frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_event {
    /// What happened.
    pub kind: psao_event_kind,
    /// The frame's sequence (for APPLIED, the mirror's new sequence).
    pub sequence: u32,
    /// 1 when the frame was a keyframe (APPLIED only), else 0.
    pub keyframe: u8,
    /// 1 when `have` holds the mirror's sequence; 0 before the first
    /// keyframe (NEED_KEYFRAME) and for APPLIED.
    pub have_valid: u8,
    /// The mirror's sequence (STALE, NEED_KEYFRAME with `have_valid`).
    pub have: u32,
    /// The sequence the frame applies to (NEED_KEYFRAME), else 0.
    pub base: u32,
}

/// What kind of range of the mirror changed.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_change_kind {
    /// The instance was defined or redefined: upload all of it.
    PSAO_CHANGE_DEFINED = 1,
    /// The instance was removed.
    PSAO_CHANGE_REMOVED = 2,
    /// The instance's transform changed.
    PSAO_CHANGE_TRANSFORM = 3,
    /// Bucket entries `[start, end)` of the instance changed.
    PSAO_CHANGE_BUCKETS = 4,
    /// Point words `[start, end)` of the instance changed.
    PSAO_CHANGE_WORDS = 5,
}

/// One changed range of the mirror.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_change {
    /// What changed.
    pub kind: psao_change_kind,
    /// The instance.
    pub instance: u32,
    /// First index of the range (BUCKETS, WORDS), else 0.
    pub start: u32,
    /// One past the last index (BUCKETS, WORDS), else 0.
    pub end: u32,
}

/// A bucket entry: the key of the cell filed there and its index in the
/// cell pool; empty entries are `{0xFFFFFFFF, 0xFFFFFFFF}`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_bucket_entry {
    /// Cell key (or link key of an overflow chain).
    pub key: u32,
    /// Cell index.
    pub cell: u32,
}

impl From<&psao_codec::BucketEntry> for psao_bucket_entry {
    fn from(e: &psao_codec::BucketEntry) -> psao_bucket_entry {
        psao_bucket_entry {
            key: e.key,
            cell: e.cell,
        }
    }
}

/// What a mirror holds for one instance.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(non_camel_case_types)]
pub struct psao_instance_info {
    /// The definition.
    pub def: psao_instance_def,
    /// 1 when `transform` holds a transform, else 0.
    pub has_transform: u8,
    /// The transform (identity with sequence 0 when there is none).
    pub transform: psao_transform,
    /// Bucket entries (`2^table_log2 * bucket_capacity`).
    pub bucket_entries: u32,
    /// Point words (`cell_pool * cell_capacity`).
    pub words: u32,
}

/// The fields of a 32-bit point word (spec/wire-format.md 6).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_point_fields {
    /// Quantized position inside the cell, per axis.
    pub position: [u32; 3],
    /// Normal code.
    pub normal: u8,
    /// AO in 1/255 steps.
    pub ao: u8,
}

/// When a point is worth sending again (the paper's thresholds);
/// `psao_thresholds_default` gives 3 quanta, cosine 0.6, 8 AO steps.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(non_camel_case_types)]
pub struct psao_thresholds {
    /// Position change in quanta of the cell.
    pub position_quanta: f32,
    /// Smallest cosine between old and new normal that is not an update.
    pub normal_cos: f32,
    /// AO change in 1/255 steps above which it is an update. A change to
    /// fully open (255) is an update whatever its size, so 255 here still
    /// sends points that come out open.
    pub ao_steps: u8,
}

impl From<Thresholds> for psao_thresholds {
    fn from(t: Thresholds) -> psao_thresholds {
        psao_thresholds {
            position_quanta: t.position_quanta,
            normal_cos: t.normal_cos,
            ao_steps: t.ao_steps,
        }
    }
}

impl From<psao_thresholds> for Thresholds {
    fn from(t: psao_thresholds) -> Thresholds {
        Thresholds {
            position_quanta: t.position_quanta,
            normal_cos: t.normal_cos,
            ao_steps: t.ao_steps,
        }
    }
}

/// Where a point of a table stands.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_placement_kind {
    /// Not in the table.
    PSAO_PLACEMENT_ABSENT = 0,
    /// Stored in `cell` at `slot`.
    PSAO_PLACEMENT_STORED = 1,
    /// Dropped (`drop_reason` says why); retried at its next update.
    PSAO_PLACEMENT_DROPPED = 2,
}

/// Why a point was dropped.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_drop_reason {
    /// Not dropped.
    PSAO_DROP_NONE = 0,
    /// Its position is outside the grid (or not finite).
    PSAO_DROP_OUT_OF_GRID = 1,
    /// Its cell is new and its bucket is full.
    PSAO_DROP_BUCKET_FULL = 2,
    /// Its cell (and overflow chain) is full.
    PSAO_DROP_CELL_FULL = 3,
    /// Its cell is new and the cell pool is exhausted.
    PSAO_DROP_POOL_EXHAUSTED = 4,
}

/// Where `psao_table_set_point` put a point.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_placement {
    /// Absent, stored or dropped.
    pub kind: psao_placement_kind,
    /// The cell (STORED), else 0xFFFFFFFF.
    pub cell: u32,
    /// The slot in the cell (STORED), else 0.
    pub slot: u8,
    /// Why it was dropped (DROPPED), else NONE.
    pub drop_reason: psao_drop_reason,
}

/// A table's counters: what it holds now, and drop events since creation.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_table_stats {
    /// Points stored now.
    pub stored: u32,
    /// Cells allocated now.
    pub cells: u32,
    /// Points set but not stored now.
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

/// Payload compression of encoded frames (spec/wire-format.md 3.2).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum psao_compression {
    /// Uncompressed.
    PSAO_COMPRESSION_NONE = 0,
    /// LZ4 block.
    PSAO_COMPRESSION_LZ4 = 1,
    /// zstd.
    PSAO_COMPRESSION_ZSTD = 2,
}

/// How an encoder writes frames; `psao_encoder_config_default` gives zstd
/// level 3 with checksums and the spec's default receiver limits.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_encoder_config {
    /// A `psao_compression` value. A frame whose compressed payload would
    /// not be smaller is sent uncompressed.
    pub compression: u32,
    /// zstd level (1 to 22; 3 is fast, the paper used 15).
    pub zstd_level: i32,
    /// 1 to add a CRC-32 to every frame (transports without integrity).
    pub checksum: u8,
    /// The receivers' limits: a frame beyond them is refused
    /// (`PSAO_ERROR_RECEIVER_LIMIT`).
    pub limits: psao_limits,
}

/// What `psao_encoder_finish` produced.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub struct psao_frame_info {
    /// The frame's sequence (with `bytes == 0`: the encoder's sequence).
    pub sequence: u32,
    /// 1 for a keyframe.
    pub keyframe: u8,
    /// Frame bytes; 0 when an empty delta produced no frame.
    pub bytes: u32,
    /// Messages, EndOfFrame included.
    pub messages: u32,
    /// Points whose words were sent.
    pub points: u32,
    /// Payload bytes before compression.
    pub payload_bytes: u32,
}
