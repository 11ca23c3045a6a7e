//! A stream of frames into one decoder and mirror. Input: repeated
//! `[u16 little-endian length][frame bytes]`. Checks, after every frame:
//! a rejected frame leaves the mirror exactly as it was; every instance's
//! buckets and cells are compacted and hold only valid words; memory stays
//! within the limit.
#![no_main]

use libfuzzer_sys::fuzz_target;
use psao_codec::{Decoder, Limits, PointWord};

fuzz_target!(|data: &[u8]| {
    let limits = Limits {
        max_payload_bytes: 1 << 16,
        max_mirror_bytes: 1 << 16,
        max_instances: 64,
        ..Limits::default()
    };
    let mut decoder = Decoder::new(limits);
    let mut rest = data;
    while rest.len() >= 2 {
        let len = u16::from_le_bytes([rest[0], rest[1]]) as usize;
        let frame = &rest[2..(2 + len).min(rest.len())];
        rest = &rest[2 + frame.len()..];
        let before = decoder.mirror().describe();
        if decoder.receive(frame).is_err() {
            assert_eq!(
                before,
                decoder.mirror().describe(),
                "rejected frame changed the mirror"
            );
        }
        let mirror = decoder.mirror();
        assert!(mirror.bytes() <= limits.max_mirror_bytes);
        for (_, m) in mirror.instances() {
            let cap = m.def().bucket_capacity as usize;
            for bucket in m.buckets().chunks(cap) {
                let used = bucket.iter().take_while(|e| !e.is_empty()).count();
                assert!(
                    bucket[used..].iter().all(|e| e.is_empty()),
                    "bucket not compacted"
                );
            }
            let cap = m.def().cell_capacity as usize;
            for cell in m.words().chunks(cap) {
                let used = cell
                    .iter()
                    .take_while(|&&w| PointWord(w).is_allocated())
                    .count();
                assert!(
                    cell.iter().all(|&w| PointWord(w).is_valid()),
                    "invalid word"
                );
                assert!(cell[used..].iter().all(|&w| w == 0), "cell not compacted");
            }
        }
    }
});
