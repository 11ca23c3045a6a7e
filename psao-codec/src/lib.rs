//! # psao-codec
//!
//! The sans-IO core of point-based split ambient occlusion (PSAO): the wire
//! format of `spec/wire-format.md`, the server's authoritative per-instance
//! hash grid ([`GridTable`]), the [`Encoder`] that turns its changes into
//! numbered frames, and the client's [`Decoder`] and [`Mirror`], with CPU
//! reconstruction of AO from the mirror ([`reconstruct_ao`], paper eq. 2-4).
//!
//! The modules follow the data path: `server` (grid table, dirty set,
//! encoder) -> [`wire`] (header, messages, compression, point words) ->
//! `client` (decoder, mirror, reconstruction); the crate root re-exports
//! what a server or a client uses, and [`wire`] holds the frame parser and
//! message layouts for those who read frames themselves.
//!
//! Nothing here does I/O or spawns threads: bytes and events in, bytes and
//! events out. Untrusted bytes never panic, never allocate beyond
//! [`Limits`], and fail with a typed [`DecodeError`]; a frame is applied to
//! the mirror whole or not at all.
//!
//! ```
//! use glam::{UVec3, Vec3};
//! use psao_codec::*;
//!
//! let def = InstanceDef {
//!     origin: Vec3::ZERO, cell_size: Vec3::splat(0.25), dims: UVec3::splat(8),
//!     table_log2: 6, bucket_capacity: 8, cell_capacity: 7, cell_pool: 512,
//!     point_format: 0, overflow: true, radius: 0.1, t_n: 0.1, t_d: 0.7,
//! };
//! let mut table = GridTable::new(7, def, 1000).unwrap();
//! let mut encoder = Encoder::new(EncoderConfig::default());
//! let mut decoder = Decoder::new(Limits::default());
//!
//! // A client joins: keyframe of the (empty) state at sequence 0.
//! let mut kf = encoder.keyframe();
//! kf.snapshot(&table).unwrap();
//! decoder.receive(&kf.finish().unwrap().unwrap().bytes).unwrap();
//!
//! // The server traces a point and streams the change.
//! table.set_point(0, Vec3::new(1.0, 0.0, 1.0), Vec3::Y, 0.5).unwrap();
//! let mut delta = encoder.delta();
//! delta.changes(&mut table);
//! let frame = delta.finish().unwrap().unwrap();
//! assert_eq!(decoder.receive(&frame.bytes).unwrap(), Event::Applied { sequence: 1, keyframe: false });
//!
//! let mirror = decoder.mirror().instance(7).unwrap();
//! assert_eq!(mirror.words(), table.words());
//! let ao = reconstruct_ao(mirror, Vec3::new(1.0, 0.0, 1.0), Vec3::Y);
//! assert!((ao - 0.5).abs() <= 1.0 / 255.0);
//! ```

mod client;
mod error;
mod grid;
mod limits;
mod server;
pub mod wire;

pub use client::decoder::Decoder;
pub use client::gpu_record::{GPU_RECORD_WORDS, gpu_instance_record};
pub use client::hidden::{
    HiddenMemo, LEAN_MAX, LEAN_MIN, NO_SURFACE, SeenSurfaces, SeenSurfacesError,
    reconstruct_ao_seen,
};
pub use client::mirror::{Change, Changes, Event, InstanceMirror, Mirror, Transform};
pub use client::reconstruct::{
    LocalFrame, WeightParams, base_cell, for_each_candidate, reconstruct_ao,
    reconstruct_ao_keeping, weight, world_to_local,
};
pub use error::{DecodeError, DecompressFault, DefError, EncodeError, MessageError};
pub use grid::{
    BucketEntry, EMPTY_KEY, InstanceDef, MAX_BUCKET_CAPACITY, MAX_CELL_CAPACITY,
    MAX_OVERFLOW_LINKS, MAX_TABLE_LOG2, OVERFLOW_FLAG, POINT_FORMAT_BIND32, POINT_FORMAT_PACKED32,
    key_fits,
};
pub use limits::Limits;
pub use server::encoder::{
    EncodedFrame, Encoder, EncoderConfig, FrameBuilder, FrameStats, PausedFrame,
};
pub use server::table::{
    DirtyCell, DirtySet, DropReason, GridTable, Placement, SentPoint, TableStats, Thresholds,
};
pub use wire::compression::Compression;
pub use wire::point::{POSITION_QUANTA, PointWord, normal_table};
