//! Helpers shared by the integration tests.
#![allow(dead_code)]

use glam::{UVec3, Vec3};
use psao_codec::*;

/// A small grid: 8x4x8 cells of 0.25 m, 64 buckets of 8, cells of 7.
pub fn small_def() -> InstanceDef {
    InstanceDef {
        origin: Vec3::new(-1.0, 0.0, -1.0),
        cell_size: Vec3::splat(0.25),
        dims: UVec3::new(8, 4, 8),
        table_log2: 6,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 256,
        point_format: POINT_FORMAT_PACKED32,
        radius: 0.2,
        t_n: 0.1,
        t_d: 0.7,
    }
}

/// Encodes a keyframe of `tables` (with their transforms) at the encoder's sequence.
pub fn keyframe(enc: &mut Encoder, tables: &[&GridTable]) -> EncodedFrame {
    let mut f = enc.keyframe();
    for t in tables {
        f.snapshot(t).unwrap();
    }
    f.finish().unwrap().unwrap()
}

/// Encodes a delta of the tables' changes, `None` if nothing changed.
pub fn delta(enc: &mut Encoder, tables: &mut [&mut GridTable]) -> Option<EncodedFrame> {
    let mut f = enc.delta();
    for t in tables.iter_mut() {
        f.changes(t);
    }
    f.finish().unwrap()
}

/// Asserts the mirror's copy of `table` equals the table.
pub fn assert_mirrors(decoder: &Decoder, table: &GridTable) {
    let m = decoder
        .mirror()
        .instance(table.id())
        .unwrap_or_else(|| panic!("instance {} missing", table.id()));
    assert_eq!(m.def(), table.def());
    assert_eq!(m.buckets(), table.buckets(), "buckets of {}", table.id());
    assert_eq!(m.words(), table.words(), "words of {}", table.id());
}
