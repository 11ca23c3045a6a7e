//! Raw builders for messages and frames, written straight from
//! spec/wire-format.md (not with psao-codec's writer), shared by the codec's
//! tests and psao-codec's `examples/gen_vectors.rs` (the spec's vectors).
//! Field names and byte orders are the spec's.

use glam::{UVec3, Vec3};
use psao_codec::wire::point::{PointFields, PointWord};
use psao_codec::{DecodeError, Event, InstanceDef};

/// Appends `v` as 4 little-endian bytes.
pub fn u32le(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// Appends `v` as 4 little-endian bytes (IEEE 754).
pub fn f32le(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// Appends `v` as a LEB128 varint.
pub fn varint(out: &mut Vec<u8>, mut v: u32) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Appends an index list: count, then first index and gaps as varints.
pub fn index_list(out: &mut Vec<u8>, idx: &[u32]) {
    let mut next = 0u32;
    for &i in idx {
        varint(out, i - next);
        next = i.wrapping_add(1);
    }
}

/// Appends `vals` byte-plane by byte-plane (all low bytes first).
pub fn planar(out: &mut Vec<u8>, vals: &[u32]) {
    for b in 0..4 {
        out.extend(vals.iter().map(|v| (v >> (8 * b)) as u8));
    }
}

/// The grid of the vectors: 4x4x4 cells of 0.5, 8 buckets of 4, cells of 4, pool 16.
pub const DEF: InstanceDef = InstanceDef {
    origin: Vec3::ZERO,
    cell_size: Vec3::splat(0.5),
    dims: UVec3::new(4, 4, 4),
    table_log2: 3,
    bucket_capacity: 4,
    cell_capacity: 4,
    cell_pool: 16,
    point_format: 0,
    overflow: false,
    radius: 0.25,
    t_n: 0.1,
    t_d: 0.7,
};

/// DefineInstance.
pub fn define(id: u32, d: &InstanceDef) -> Vec<u8> {
    let mut o = vec![0x01];
    u32le(&mut o, id);
    for f in d
        .origin
        .to_array()
        .into_iter()
        .chain(d.cell_size.to_array())
    {
        f32le(&mut o, f);
    }
    for x in d.dims.to_array() {
        u32le(&mut o, x);
    }
    o.extend_from_slice(&[
        d.table_log2,
        d.bucket_capacity,
        d.cell_capacity,
        d.point_format | if d.overflow { 0x80 } else { 0 },
    ]);
    u32le(&mut o, d.cell_pool);
    for f in [d.radius, d.t_n, d.t_d] {
        f32le(&mut o, f);
    }
    o
}

/// RemoveInstance.
pub fn remove(id: u32) -> Vec<u8> {
    let mut o = vec![0x02];
    u32le(&mut o, id);
    o
}

/// Transform: identity rotation, translation (tx, 2, 0).
pub fn transform(id: u32, seq: u32, tx: f32) -> Vec<u8> {
    let mut o = vec![0x03];
    u32le(&mut o, id);
    u32le(&mut o, seq);
    for f in [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, tx, 2.0, 0.0] {
        f32le(&mut o, f);
    }
    o
}

/// BucketEntries: per bucket, its entries as (key, cell).
pub fn buckets(id: u32, list: &[(u32, &[(u32, u32)])]) -> Vec<u8> {
    let mut o = vec![0x04];
    u32le(&mut o, id);
    u32le(&mut o, list.len() as u32);
    index_list(&mut o, &list.iter().map(|b| b.0).collect::<Vec<_>>());
    o.extend(list.iter().map(|b| b.1.len() as u8));
    let keys: Vec<u32> = list.iter().flat_map(|b| b.1.iter().map(|e| e.0)).collect();
    let cells: Vec<u32> = list.iter().flat_map(|b| b.1.iter().map(|e| e.1)).collect();
    planar(&mut o, &keys);
    planar(&mut o, &cells);
    o
}

/// CellWords, full words: per cell, its words.
pub fn cells_full(id: u32, list: &[(u32, &[u32])]) -> Vec<u8> {
    let mut o = vec![0x05];
    u32le(&mut o, id);
    u32le(&mut o, list.len() as u32);
    index_list(&mut o, &list.iter().map(|c| c.0).collect::<Vec<_>>());
    o.extend(list.iter().map(|c| c.1.len() as u8));
    planar(
        &mut o,
        &list
            .iter()
            .flat_map(|c| c.1.iter().copied())
            .collect::<Vec<_>>(),
    );
    o
}

/// CellWords, XOR against the held words: per cell, its count and words.
pub fn cells_xor(id: u32, list: &[(u32, u8, &[u32])]) -> Vec<u8> {
    let mut o = vec![0x06];
    u32le(&mut o, id);
    u32le(&mut o, list.len() as u32);
    index_list(&mut o, &list.iter().map(|c| c.0).collect::<Vec<_>>());
    o.extend(list.iter().map(|c| c.1));
    planar(
        &mut o,
        &list
            .iter()
            .flat_map(|c| c.2.iter().copied())
            .collect::<Vec<_>>(),
    );
    o
}

/// CellAo: per cell, its count and AO bytes.
pub fn cells_ao(id: u32, list: &[(u32, u8, &[u8])]) -> Vec<u8> {
    let mut o = vec![0x07];
    u32le(&mut o, id);
    u32le(&mut o, list.len() as u32);
    index_list(&mut o, &list.iter().map(|c| c.0).collect::<Vec<_>>());
    o.extend(list.iter().map(|c| c.1));
    o.extend(list.iter().flat_map(|c| c.2.iter().copied()));
    o
}

/// FreeCells.
pub fn free(id: u32, cells: &[u32]) -> Vec<u8> {
    let mut o = vec![0x08];
    u32le(&mut o, id);
    u32le(&mut o, cells.len() as u32);
    index_list(&mut o, cells);
    o
}

/// EndOfFrame.
pub const END: [u8; 1] = [0x00];

/// A packed32 point word from its fields.
pub fn word(pos: [u32; 3], normal: u8, ao: u8) -> u32 {
    PointWord::pack(PointFields {
        position: UVec3::from(pos),
        normal,
        ao,
    })
    .0
}

/// A frame header and its messages, to be written by [`Frame::bytes`].
#[derive(Clone)]
pub struct Frame {
    /// The header's `keyframe`.
    pub keyframe: bool,
    /// The header's `checksum`.
    pub checksum: bool,
    /// The header's `compression`.
    pub compression: u8,
    /// The header's `seq`.
    pub seq: u32,
    /// The header's `base`.
    pub base: u32,
    /// The header's `messages`.
    pub messages: Vec<Vec<u8>>,
    /// Overrides `message_count` (default: number of messages).
    pub count: Option<u32>,
    /// Overrides the payload bytes on the wire (default: the messages,
    /// compressed with `compression`); `uncompressed_len` stays the
    /// messages' length.
    pub wire: Option<Vec<u8>>,
}

/// An uncompressed keyframe without checksum at `seq`.
pub fn key(seq: u32, messages: Vec<Vec<u8>>) -> Frame {
    Frame {
        keyframe: true,
        checksum: false,
        compression: 0,
        seq,
        base: seq,
        messages,
        count: None,
        wire: None,
    }
}

/// An uncompressed delta from `base` to `seq` without checksum.
pub fn delta(seq: u32, base: u32, messages: Vec<Vec<u8>>) -> Frame {
    Frame {
        keyframe: false,
        base,
        ..key(seq, messages)
    }
}

impl Frame {
    /// The frame on the wire: header, (compressed) payload, checksum.
    pub fn bytes(&self) -> Vec<u8> {
        let payload: Vec<u8> = self.messages.concat();
        let wire = match (&self.wire, self.compression) {
            (Some(w), _) => w.clone(),
            (None, 0) => payload.clone(),
            (None, 1) => lz4_flex::block::compress(&payload),
            (None, _) => zstd::bulk::compress(&payload, 3).expect("zstd"),
        };
        let mut h = Vec::with_capacity(32 + wire.len());
        h.extend_from_slice(b"PSAO");
        h.push(1);
        h.push(self.keyframe as u8 | (self.checksum as u8) << 1);
        h.push(self.compression);
        h.push(0);
        u32le(&mut h, self.seq);
        u32le(&mut h, self.base);
        u32le(&mut h, self.count.unwrap_or(self.messages.len() as u32));
        u32le(&mut h, payload.len() as u32);
        u32le(&mut h, wire.len() as u32);
        let crc = if self.checksum {
            let mut c = crc32fast::Hasher::new();
            c.update(&h);
            c.update(&wire);
            c.finalize()
        } else {
            0
        };
        u32le(&mut h, crc);
        h.extend_from_slice(&wire);
        h
    }
}

/// A zstd frame written by hand from RFC 8878 3.1.1: no content size, no
/// checksum, no dictionary, the window descriptor `window` (exponent in bits
/// 7-3, mantissa in bits 2-0), and `data` as one raw last block.
pub fn zstd_raw_frame(window: u8, data: &[u8]) -> Vec<u8> {
    let mut f = 0xFD2F_B528u32.to_le_bytes().to_vec();
    f.extend([0x00, window]);
    let block = 1 | (data.len() as u32) << 3; // Last_Block, Block_Type 0 (raw)
    f.extend(&block.to_le_bytes()[..3]);
    f.extend(data);
    f
}

/// A zstd skippable frame (RFC 8878 3.1.2, magic `0x184D2A53`) of `n`
/// user bytes.
pub fn zstd_skippable(n: usize) -> Vec<u8> {
    let mut f = 0x184D_2A53u32.to_le_bytes().to_vec();
    u32le(&mut f, n as u32);
    f.extend(std::iter::repeat_n(0x5A, n));
    f
}

/// Appends one LZ4 sequence (the LZ4 block format): `literals`, then a
/// match of `len >= 4` bytes `offset` back, if any.
pub fn lz4_sequence(out: &mut Vec<u8>, literals: &[u8], matched: Option<(u16, usize)>) {
    fn ext(out: &mut Vec<u8>, mut n: usize) {
        while n >= 255 {
            out.push(255);
            n -= 255;
        }
        out.push(n as u8);
    }
    let m = matched.map_or(0, |(_, len)| len - 4);
    out.push((literals.len().min(15) as u8) << 4 | m.min(15) as u8);
    if literals.len() >= 15 {
        ext(out, literals.len() - 15);
    }
    out.extend_from_slice(literals);
    if let Some((offset, _)) = matched {
        out.extend(offset.to_le_bytes());
        if m >= 15 {
            ext(out, m - 15);
        }
    }
}

/// An LZ4 block that decodes to `payload` but breaks the end-of-block rule
/// "the last match starts at least 12 bytes before the end": literals, one
/// 4-byte match as late as `payload` allows, the rest as literals. A
/// lenient decoder (lz4_flex) decodes it; liblz4 and the spec refuse it.
///
/// # Panics
/// If no 4 bytes among the last 12 repeat earlier ones.
pub fn lz4_late_match(payload: &[u8]) -> Vec<u8> {
    let n = payload.len();
    let (j, d) = (n.saturating_sub(11).max(1)..n.saturating_sub(3))
        .rev()
        .find_map(|j| {
            (1..=j.min(65_535))
                .find(|&d| payload[j..j + 4] == payload[j - d..j - d + 4])
                .map(|d| (j, d))
        })
        .expect("a repeated 4-byte run in the last 12 bytes");
    let mut block = Vec::new();
    lz4_sequence(&mut block, &payload[..j], Some((d as u16, 4)));
    lz4_sequence(&mut block, &payload[j + 4..], None);
    block
}

/// An undefined message type: makes any frame fail where it stands.
pub fn invalid() -> Vec<u8> {
    vec![0x09]
}

/// An uncompressed frame without checksum; EndOfFrame is appended.
pub fn frame(keyframe: bool, seq: u32, base: u32, messages: &[Vec<u8>]) -> Vec<u8> {
    let mut messages = messages.to_vec();
    messages.push(END.to_vec());
    let f = if keyframe {
        key(seq, messages)
    } else {
        delta(seq, base, messages)
    };
    f.bytes()
}

/// The `expect` line of spec/vectors for a decoder's answer to a frame.
///
/// # Panics
/// On an event spec/vectors has no line for (none today: `Event` is
/// `#[non_exhaustive]`, and a new one needs its line in the spec first).
pub fn outcome(r: &Result<Event, DecodeError>) -> String {
    match r {
        Ok(Event::Applied { sequence, keyframe }) => {
            let kind = if *keyframe { "keyframe" } else { "delta" };
            format!("applied {sequence} {kind}")
        }
        Ok(Event::Stale { .. }) => "stale".into(),
        Ok(Event::NeedKeyframe { .. }) => "need_keyframe".into(),
        Ok(e) => panic!("no vector line for the event {e:?} yet"),
        Err(e) => format!("error {}", e.code()),
    }
}
