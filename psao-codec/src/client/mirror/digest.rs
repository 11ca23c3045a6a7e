//! The mirror digest of spec/wire-format.md 7.5: a CRC-32 over a
//! canonical serialization of the whole state (sequence, then each
//! instance's definition, transform, bucket entries and words), so a
//! client can check its mirror against the server's without a copy.

use crate::grid::BucketEntry;
use crate::wire::message::write;

use super::Mirror;

/// Feeds little-endian `u32`s to `h` through a stack buffer.
fn update_u32s(h: &mut crc32fast::Hasher, values: impl Iterator<Item = u32>) {
    let mut buf = [0u8; 4096];
    let mut n = 0;
    for v in values {
        buf[n..n + 4].copy_from_slice(&v.to_le_bytes());
        n += 4;
        if n == buf.len() {
            h.update(&buf);
            n = 0;
        }
    }
    h.update(&buf[..n]);
}

impl Mirror {
    /// The digest of the state (spec/wire-format.md 7.5); `None` before
    /// the first keyframe. It reads every byte of the mirror once
    /// (about 1 ms per 10 MB): compute it when a digest is to be checked,
    /// not per frame.
    pub fn digest(&self) -> Option<u32> {
        let sequence = self.sequence?;
        let mut h = crc32fast::Hasher::new();
        h.update(&sequence.to_le_bytes());
        h.update(&(self.instances.len() as u32).to_le_bytes());
        let mut def = Vec::with_capacity(61);
        for (&id, m) in &self.instances {
            h.update(&id.to_le_bytes());
            def.clear();
            write::define(&mut def, id, &m.def);
            h.update(&def[5..]);
            match &m.transform {
                Some(t) => {
                    h.update(&[1]);
                    h.update(&t.sequence.to_le_bytes());
                    update_u32s(&mut h, t.matrix.iter().map(|f| f.to_bits()));
                }
                None => h.update(&[0]),
            }
            update_u32s(
                &mut h,
                m.buckets.iter().flat_map(|e: &BucketEntry| [e.key, e.cell]),
            );
            update_u32s(&mut h, m.words.iter().copied());
        }
        Some(h.finalize())
    }
}
