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

/// Raw message and frame builders, straight from spec/wire-format.md.
pub mod raw {
    use psao_codec::InstanceDef;

    fn varint(out: &mut Vec<u8>, mut v: u32) {
        while v >= 0x80 {
            out.push(v as u8 | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }

    fn index_list(out: &mut Vec<u8>, idx: &[u32]) {
        let mut next = 0u32;
        for &i in idx {
            varint(out, i - next);
            next = i + 1;
        }
    }

    /// DefineInstance.
    pub fn define(id: u32, d: &InstanceDef) -> Vec<u8> {
        let mut o = vec![0x01];
        o.extend_from_slice(&id.to_le_bytes());
        for f in d
            .origin
            .to_array()
            .into_iter()
            .chain(d.cell_size.to_array())
        {
            o.extend_from_slice(&f.to_le_bytes());
        }
        for x in d.dims.to_array() {
            o.extend_from_slice(&x.to_le_bytes());
        }
        o.extend_from_slice(&[
            d.table_log2,
            d.bucket_capacity,
            d.cell_capacity,
            d.point_format,
        ]);
        o.extend_from_slice(&d.cell_pool.to_le_bytes());
        for f in [d.radius, d.t_n, d.t_d] {
            o.extend_from_slice(&f.to_le_bytes());
        }
        o
    }

    /// RemoveInstance.
    pub fn remove(id: u32) -> Vec<u8> {
        let mut o = vec![0x02];
        o.extend_from_slice(&id.to_le_bytes());
        o
    }

    /// Buckets emptying the listed buckets.
    pub fn empty_buckets(id: u32, buckets: &[u32]) -> Vec<u8> {
        let mut o = vec![0x04];
        o.extend_from_slice(&id.to_le_bytes());
        o.extend_from_slice(&(buckets.len() as u32).to_le_bytes());
        index_list(&mut o, buckets);
        o.extend(std::iter::repeat_n(0u8, buckets.len()));
        o
    }

    /// CellsFree.
    pub fn free(id: u32, cells: &[u32]) -> Vec<u8> {
        let mut o = vec![0x08];
        o.extend_from_slice(&id.to_le_bytes());
        o.extend_from_slice(&(cells.len() as u32).to_le_bytes());
        index_list(&mut o, cells);
        o
    }

    /// An undefined message type: makes any frame fail where it stands.
    pub fn invalid() -> Vec<u8> {
        vec![0x09]
    }

    /// An uncompressed frame without checksum; EndOfFrame is appended.
    pub fn frame(keyframe: bool, seq: u32, base: u32, messages: &[Vec<u8>]) -> Vec<u8> {
        let mut payload: Vec<u8> = messages.concat();
        payload.push(0);
        let mut f = b"PSAO".to_vec();
        f.extend_from_slice(&[1, keyframe as u8, 0, 0]);
        for v in [
            seq,
            base,
            messages.len() as u32 + 1,
            payload.len() as u32,
            payload.len() as u32,
            0,
        ] {
            f.extend_from_slice(&v.to_le_bytes());
        }
        f.extend_from_slice(&payload);
        f
    }
}
