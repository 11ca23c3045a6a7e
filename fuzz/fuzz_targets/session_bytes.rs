//! Untrusted session bytes (spec/session.md, spec/capture.md): the first
//! byte picks what reads the rest, fed in irregular chunks. Nothing may
//! panic; readers never hold more than their bound; a client's mirror
//! stays valid.
#![no_main]

use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use psao_proto::capture::CaptureReader;
use psao_proto::{ClientConfig, ClientSession, Offer, ServerConn};

fn chunks(data: &[u8]) -> impl Iterator<Item = &[u8]> {
    // Chunk sizes from the data itself: 1, 2, 3, ... bytes, cycling.
    let mut at = 0;
    let mut k = 0;
    std::iter::from_fn(move || {
        if at >= data.len() {
            return None;
        }
        k = k % 17 + 1;
        let end = (at + k).min(data.len());
        let c = &data[at..end];
        at = end;
        Some(c)
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    match which % 4 {
        0 => {
            let offer = Offer {
                compression: 2,
                max_frame_bytes: 1 << 20,
                max_payload_bytes: 1 << 20,
                // Frames sent so far: HELLOs below are refused.
                largest_frame: 100_000,
                largest_payload: 100_000,
                mirror_bytes: 1 << 16,
                // Bind space half the time: negotiation refuses clients
                // without point format 1.
                point_format: which / 4 % 2,
                // Overflow chains half the time, independently: refused
                // to clients without flags.overflow.
                overflow: which / 8 % 2 == 1,
                frame_rate: 60,
                scene: "fuzz".into(),
                culling: true,
                // Digests half the time.
                digest: which / 16 % 2 == 1,
            };
            let t0 = Instant::now();
            let mut s = ServerConn::new(offer, t0);
            let mut events = Vec::new();
            for (i, c) in chunks(rest).enumerate() {
                let now = t0 + Duration::from_millis(i as u64);
                if s.on_control(c, now, &mut events).is_err() {
                    break;
                }
            }
        }
        1 | 2 => {
            let mut c = ClientSession::new(ClientConfig::default());
            for chunk in chunks(rest) {
                let r = if which % 4 == 1 {
                    c.on_control(chunk)
                } else {
                    c.on_frames(chunk)
                };
                if r.is_err() {
                    break;
                }
                while c.poll_event().is_some() {}
                let _ = c.take_transmit();
            }
            // The mirror stays within the client's limits.
            let bytes: u64 = c
                .mirror()
                .instances()
                .map(|(_, m)| m.words().len() as u64 * 4 + m.buckets().len() as u64 * 8)
                .sum();
            assert!(bytes <= psao_codec::Limits::default().max_mirror_bytes);
        }
        _ => {
            if let Ok(r) = CaptureReader::new(rest, 1 << 16) {
                for rec in r.flatten() {
                    assert!(rec.frame.len() <= 1 << 16);
                }
            }
        }
    }
});
