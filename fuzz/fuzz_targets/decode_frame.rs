//! Any bytes into `decode_frame`: never panics; a frame that passes walks
//! its messages without error and stays within the limits.
#![no_main]

use libfuzzer_sys::fuzz_target;
use psao_codec::Limits;
use psao_codec::wire::{Scratch, decode_frame};

fuzz_target!(|data: &[u8]| {
    let limits = Limits {
        max_payload_bytes: 1 << 20,
        ..Limits::default()
    };
    let mut scratch = Scratch::default();
    if let Ok(view) = decode_frame(data, &limits, &mut scratch) {
        assert!(view.payload().len() <= limits.max_payload_bytes as usize);
        assert_eq!(
            view.payload().len(),
            view.header().uncompressed_len as usize
        );
        let mut n = 0u32;
        for m in view.messages() {
            m.expect("decode_frame checked the syntax of every message");
            n += 1;
        }
        assert_eq!(n + 1, view.header().message_count);
    }
});
