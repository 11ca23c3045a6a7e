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
        overflow: false,
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

/// Every overflow chain of a table is compacted (spec/wire-format.md 7.4):
/// a grid cell's links `0..=L` are all present, each but the last full,
/// none empty; and every bucket key names a link of a cell.
pub fn assert_chains_compacted(t: &GridTable) {
    let def = *t.def();
    let mut chains: std::collections::BTreeMap<u32, Vec<(u8, u32)>> = Default::default();
    for b in 0..def.table_size() {
        for e in t.bucket(b) {
            let (cell, link) = def
                .link_of_key(e.key)
                .unwrap_or_else(|| panic!("key {} names no link", e.key));
            chains
                .entry(def.key(cell))
                .or_default()
                .push((link, e.cell));
        }
    }
    for (key, mut links) in chains {
        links.sort_unstable();
        let last = links.len() - 1;
        for (i, &(link, cell)) in links.iter().enumerate() {
            assert_eq!(link as usize, i, "chain of key {key}: {links:?}");
            let n = t.cell_len(cell);
            assert!(n > 0, "chain of key {key}: link {i} is empty");
            if i < last {
                assert_eq!(
                    n, def.cell_capacity,
                    "chain of key {key}: link {i} not full"
                );
            }
        }
    }
}
