//! Frames built to exhaust a decoder: repeated redefinitions, repeated
//! writes to the same state, change-list overflow. Each must fail with a
//! typed error within the configured limits and leave the mirror as it was.

mod common;

use common::small_def;
use glam::Vec3;
use psao_codec::*;
use psao_tests::raw;

fn synced(limits: Limits) -> Decoder {
    let mut d = Decoder::new(limits);
    let kf = raw::frame(true, 1, 1, &[raw::define(1, &small_def())]);
    assert_eq!(
        d.receive(&kf).unwrap(),
        Event::Applied {
            sequence: 1,
            keyframe: true
        }
    );
    d
}

#[test]
fn repeated_redefinitions_are_bounded_by_the_allocation_budget() {
    let limits = Limits {
        max_mirror_bytes: 64 << 20,
        ..Limits::default()
    };
    let mut d = synced(limits);
    let before = d.mirror().describe();
    // 8 MiB of bucket entries per definition: the 8th exceeds 64 MiB.
    let big = InstanceDef {
        table_log2: 16,
        bucket_capacity: 16,
        ..small_def()
    };
    assert!(big.mirror_bytes() > 8 << 20);
    let msgs: Vec<Vec<u8>> = (0..40).map(|_| raw::define(1, &big)).collect();
    let err = d.receive(&raw::frame(false, 2, 1, &msgs)).unwrap_err();
    assert_eq!(err.code(), "resource_limit");
    assert!(
        matches!(err, DecodeError::Message { index: 7, .. }),
        "{err}"
    );
    assert_eq!(d.mirror().describe(), before);
    // Alternating define and remove is bounded the same way.
    let msgs: Vec<Vec<u8>> = (0..40)
        .flat_map(|_| [raw::define(2, &big), raw::remove(2)])
        .collect();
    assert_eq!(
        d.receive(&raw::frame(false, 2, 1, &msgs))
            .unwrap_err()
            .code(),
        "resource_limit"
    );
    assert_eq!(d.mirror().describe(), before);
    // Within the budget, the last definition wins and nothing leaks into
    // the state: instance 1 redefined twice, instance 3 created and removed.
    let msgs = vec![
        raw::define(1, &small_def()),
        raw::define(1, &small_def()),
        raw::define(3, &small_def()),
        raw::remove(3),
    ];
    d.receive(&raw::frame(false, 2, 1, &msgs)).unwrap();
    assert!(d.mirror().instance(3).is_none());
    assert_eq!(d.mirror().bytes(), small_def().mirror_bytes() as u64);
}

#[test]
fn rewriting_the_same_state_is_bounded_by_the_journal_budget() {
    let def = small_def();
    let limits = Limits {
        max_mirror_bytes: 4 * def.mirror_bytes() as u64,
        ..Limits::default()
    };
    let mut d = synced(limits);
    let before = d.mirror().describe();
    // Each message re-saves all 64 buckets (4 KiB + entries): cheap on the
    // wire, costly in the journal.
    let all: Vec<u32> = (0..def.table_size()).collect();
    let msgs: Vec<Vec<u8>> = (0..64)
        .map(|_| raw::buckets(1, &all.iter().map(|&b| (b, &[][..])).collect::<Vec<_>>()))
        .collect();
    let err = d.receive(&raw::frame(false, 2, 1, &msgs)).unwrap_err();
    assert_eq!(err.code(), "resource_limit");
    assert_eq!(d.mirror().describe(), before);
    // A frame that touches each bucket once fits.
    d.receive(&raw::frame(false, 2, 1, &msgs[..1])).unwrap();
}

#[test]
fn failed_frame_never_under_reports_changes() {
    let def = InstanceDef {
        table_log2: 1,
        cell_capacity: 1,
        cell_pool: 140_000,
        ..small_def()
    };
    let mut d = Decoder::new(Limits::default());
    d.receive(&raw::frame(true, 1, 1, &[raw::define(1, &def)]))
        .unwrap();
    d.mirror_mut().clear_changes();
    // An applied frame leaves a pending change the renderer has not taken.
    d.receive(&raw::frame(false, 2, 1, &[raw::free(1, &[5])]))
        .unwrap();
    assert_eq!(d.mirror().changes().items, vec![Change::Words(1, 5..6)]);
    // A failing frame that overflows the change list: the pending change
    // must not be lost (the list may over-report as `all`).
    let every_other: Vec<u32> = (0..70_000).map(|i| i * 2).collect();
    let f = raw::frame(false, 3, 2, &[raw::free(1, &every_other), raw::invalid()]);
    assert!(d.receive(&f).is_err());
    let c = d.mirror().changes();
    assert!(c.all || c.items.contains(&Change::Words(1, 5..6)));
    // A failing frame that merged into the last pending range restores it.
    d.mirror_mut().clear_changes();
    d.receive(&raw::frame(false, 3, 2, &[raw::free(1, &[5])]))
        .unwrap();
    let f = raw::frame(false, 4, 3, &[raw::free(1, &[6]), raw::invalid()]);
    assert!(d.receive(&f).is_err());
    assert_eq!(d.mirror().changes().items, vec![Change::Words(1, 5..6)]);
    assert!(!d.mirror().changes().all);
}

#[test]
fn encoder_respects_receiver_limits_and_skips_a_failed_delta() {
    let mut table = GridTable::new(1, small_def(), 64).unwrap();
    let mut enc = Encoder::new(EncoderConfig {
        compression: Compression::None,
        limits: Limits {
            max_payload_bytes: 120,
            ..Limits::default()
        },
        ..EncoderConfig::default()
    });
    let mut client = Decoder::new(Limits::default());
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    client
        .receive(&kf.finish().unwrap().unwrap().bytes)
        .unwrap();
    // Too many changes for one 120-byte payload.
    for i in 0..40 {
        table
            .set_point(
                i,
                Vec3::new(-0.95 + i as f32 * 0.045, 0.1, 0.3),
                Vec3::Y,
                0.5,
            )
            .unwrap();
    }
    let mut f = enc.delta();
    f.changes(&mut table);
    assert!(matches!(
        f.finish(),
        Err(EncodeError::ReceiverLimit {
            what: "payload bytes",
            ..
        })
    ));
    assert_eq!(enc.sequence(), 1, "the failed delta's sequence is skipped");
    // The next delta is based on 1: the client (at 0) asks for a keyframe.
    table
        .set_point(0, Vec3::new(0.5, 0.5, 0.5), Vec3::Y, 0.1)
        .unwrap();
    let mut f = enc.delta();
    f.changes(&mut table);
    let next = f.finish().unwrap().unwrap();
    assert!(matches!(
        client.receive(&next.bytes).unwrap(),
        Event::NeedKeyframe {
            have: Some(0),
            base: 1,
            ..
        }
    ));
    enc.set_config(EncoderConfig {
        compression: Compression::None,
        ..EncoderConfig::default()
    });
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    client
        .receive(&kf.finish().unwrap().unwrap().bytes)
        .unwrap();
    assert_eq!(client.mirror().instance(1).unwrap().words(), table.words());
}

#[test]
fn reconstruction_never_returns_nan() {
    let p = WeightParams {
        radius: 0.2,
        t_n: 0.1,
        t_d: 0.7,
        noise: 0.001,
    };
    for (pp, x, n) in [
        (Vec3::NAN, Vec3::ZERO, Vec3::Y),
        (Vec3::ZERO, Vec3::NAN, Vec3::Y),
        (Vec3::ZERO, Vec3::ZERO, Vec3::NAN),
        (Vec3::splat(f32::INFINITY), Vec3::ZERO, Vec3::Y),
    ] {
        assert_eq!(weight(pp, Vec3::Y, x, n, &p), 0.0, "{pp:?} {x:?} {n:?}");
    }
    // Huge but finite inputs give a number, not NaN.
    for n in [
        Vec3::splat(1e30),
        Vec3::splat(f32::MAX),
        Vec3::new(f32::MAX, -f32::MAX, 0.0),
    ] {
        assert!(!weight(Vec3::ZERO, n, Vec3::ZERO, n, &p).is_nan());
    }
    let singular = glam::Affine3A::from_cols_array(&[f32::NAN; 12]);
    assert!(world_to_local(&singular, Vec3::ZERO, Vec3::Y).is_none());
    let huge = glam::Affine3A::from_scale(Vec3::splat(1e-20));
    assert!(world_to_local(&huge, Vec3::ONE, Vec3::Y).is_none());
}

/// Needs the C library's zstd: the encoder compresses with it, and the test
/// re-frames the payload it decompresses.
#[cfg(feature = "zstd")]
#[test]
fn xor_and_ao_deltas_roll_back_by_their_inverse() {
    // A mirror with points in several cells, through a real keyframe.
    let mut table = GridTable::new(1, small_def(), 64).unwrap();
    for i in 0..40u32 {
        let p = Vec3::new(
            -0.95 + (i % 8) as f32 * 0.25,
            0.1 + (i / 8) as f32 * 0.2,
            0.3,
        );
        table.set_point(i, p, Vec3::Y, i as f32 / 40.0).unwrap();
    }
    table.take_dirty();
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let mut d = Decoder::new(Limits::default());
    d.receive(&kf.finish().unwrap().unwrap().bytes).unwrap();
    let before = d.mirror().describe();
    // A real delta moving AO and normals of many points, with an invalid
    // message appended: its XOR and AO messages apply, then all roll back.
    for i in 0..40u32 {
        let p = Vec3::new(
            -0.95 + (i % 8) as f32 * 0.25,
            0.1 + (i / 8) as f32 * 0.2,
            0.3,
        );
        let n = if i % 3 == 0 { Vec3::X } else { Vec3::Y };
        table.set_point(i, p, n, 1.0 - i as f32 / 40.0).unwrap();
    }
    let mut f = enc.delta();
    f.changes(&mut table);
    let good = f.finish().unwrap().unwrap();
    assert!(
        good.stats.cells_xor > 0 && good.stats.cells_ao > 0,
        "{:?}",
        good.stats
    );
    // Re-frame its payload with a message that fails when it applies (a
    // state-layer error: a syntax error would stop the frame before any
    // message applied).
    use psao_codec::wire::{FrameHeader, HEADER_LEN};
    let h = FrameHeader::parse(&good.bytes).unwrap();
    assert_eq!(h.compression, Compression::Zstd);
    let payload = zstd::bulk::decompress(&good.bytes[HEADER_LEN..], 1 << 20).unwrap();
    let body = payload[..payload.len() - 1].to_vec();
    let bad = raw::frame(false, 1, 0, &[body.clone(), raw::remove(999)]);
    // raw::frame counts messages by slices: fix the count in the header.
    let mut bad = bad;
    bad[16..20].copy_from_slice(&(h.message_count + 1).to_le_bytes());
    let err = d.receive(&bad).unwrap_err();
    assert_eq!(err.code(), "unknown_instance", "{err}");
    assert_eq!(d.mirror().describe(), before);
    // The good frame still applies on top.
    d.receive(&good.bytes).unwrap();
    assert_eq!(d.mirror().instance(1).unwrap().words(), table.words());
}

#[test]
fn definitions_with_huge_tables_are_refused_without_overflow() {
    // table_log2 up to 255 times a bucket capacity of 255: the size
    // arithmetic is exact (found by fuzzing with overflow checks on).
    for table_log2 in [32u8, 57, 63, 64, 200, 255] {
        let def = InstanceDef {
            table_log2,
            bucket_capacity: 255,
            ..small_def()
        };
        assert_eq!(def.validate(), Err(DefError::TableSize), "{table_log2}");
    }
}
