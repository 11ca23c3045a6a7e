//! Untrusted MoQ objects (spec/moq.md): what a relay hands a subscriber's
//! [`Follower`], as a program of catalog, frame, digest and restart
//! operations. Nothing may panic; the mirror stays within the follower's
//! limits; an applied frame leaves the mirror at the sequence it reports.
//!
//! Each operation starts with a byte whose value modulo 4 picks it:
//! 0 catalog (`u8` length, body), 1 frame (`u16` group, `u8` index, `u16`
//! length, body; little-endian), 2 digest (`u8` length, body), 3 restart.
#![no_main]

use libfuzzer_sys::fuzz_target;
use psao_codec::Limits;
use psao_moq::{Followed, Follower};

/// Takes `n` bytes, or what is left.
fn take<'a>(data: &mut &'a [u8], n: usize) -> &'a [u8] {
    let (head, tail) = data.split_at(n.min(data.len()));
    *data = tail;
    head
}

fn int(data: &mut &[u8], n: usize) -> u64 {
    take(data, n)
        .iter()
        .rev()
        .fold(0u64, |v, &b| (v << 8) | u64::from(b))
}

fuzz_target!(|data: &[u8]| {
    // A small mirror cap, so the limit is reached.
    let limits = Limits {
        max_mirror_bytes: 1 << 18,
        ..Limits::default()
    };
    let mut f = Follower::new(limits);
    let mut data = data;
    while let Some((&op, rest)) = data.split_first() {
        data = rest;
        match op % 4 {
            0 => {
                let n = int(&mut data, 1) as usize;
                let _ = f.on_catalog(take(&mut data, n));
            }
            1 => {
                let group = int(&mut data, 2);
                let index = int(&mut data, 1);
                let n = int(&mut data, 2) as usize;
                let frame = take(&mut data, n);
                if let Followed::Applied { sequence, .. } = f.on_frame(group, index, frame) {
                    assert_eq!(f.mirror().sequence(), Some(sequence));
                }
            }
            2 => {
                let n = int(&mut data, 1) as usize;
                let _ = f.on_digest(take(&mut data, n));
            }
            _ => f.restart(),
        }
        let bytes: u64 = f
            .mirror()
            .instances()
            .map(|(_, m)| m.words().len() as u64 * 4 + m.buckets().len() as u64 * 8)
            .sum();
        assert!(bytes <= limits.max_mirror_bytes, "{bytes} mirror bytes");
        let _ = (f.in_sync(), f.gave_up(), f.stats());
    }
});
