//! Differential fuzzing of the frame layer (issue 16): psao-codec's
//! `decode_frame` against the independent reference of
//! `psao_tests::reference` (written from spec/wire-format.md 3, with its
//! own LZ4 decoder and libzstd's streaming path). They must give the same
//! error class, or the same payload. The first byte picks the input: odd,
//! the rest is a whole frame; even, the rest after two length bytes is an
//! LZ4 (byte 0 / 2 % 2 == 0) or zstd payload wrapped in a correct header,
//! so mutations reach the decompressors.
#![no_main]

use libfuzzer_sys::fuzz_target;
use psao_codec::Limits;
use psao_tests::reference::{compare, frame_around};

fuzz_target!(|data: &[u8]| {
    let limits = Limits {
        max_payload_bytes: 1 << 20,
        ..Limits::default()
    };
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let frame = if mode % 2 == 1 || rest.len() < 2 {
        rest.to_vec()
    } else {
        let n = u16::from_le_bytes([rest[0], rest[1]]) as u32;
        let compression = if mode / 2 % 2 == 0 { 1 } else { 2 };
        frame_around(&rest[2..], compression, n, true)
    };
    if let Err(e) = compare(&frame, &limits) {
        panic!("the decoder and the reference disagree: {e}");
    }
});
