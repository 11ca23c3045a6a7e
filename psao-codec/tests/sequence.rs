//! Sequence numbers: gaps, duplicates, reordering, wrap-around, keyframes,
//! transform sequences, and all-or-nothing application.

mod common;

use common::*;
use glam::Vec3;
use psao_codec::wire::sequence;
use psao_codec::*;

/// A server with one table that produces a delta per call.
struct Server {
    table: GridTable,
    enc: Encoder,
    step: u32,
}

impl Server {
    fn new(start: u32) -> Server {
        Server {
            table: GridTable::new(1, small_def(), 64).unwrap(),
            enc: Encoder::starting_at(EncoderConfig::default(), start),
            step: 0,
        }
    }

    fn keyframe(&mut self) -> EncodedFrame {
        keyframe(&mut self.enc, &[&self.table])
    }

    fn next(&mut self) -> EncodedFrame {
        self.step += 1;
        let x = (self.step % 7) as f32 * 0.2 - 0.7;
        let ao = (self.step % 5) as f32 / 5.0;
        self.table
            .set_point(self.step % 40, Vec3::new(x, 0.3, 0.1), Vec3::Y, ao)
            .unwrap();
        delta(&mut self.enc, &mut [&mut self.table]).expect("a change was made")
    }
}

#[test]
fn delta_before_keyframe_asks_for_keyframe() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    let f = s.next();
    assert_eq!(
        d.receive(&f.bytes).unwrap(),
        Event::NeedKeyframe {
            have: None,
            base: 0,
            sequence: 1
        }
    );
    assert!(d.mirror().instance(1).is_none());
}

#[test]
fn gap_asks_for_keyframe_and_keyframe_resyncs() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let f1 = s.next();
    let _lost = s.next();
    let f3 = s.next();
    assert!(matches!(
        d.receive(&f1.bytes).unwrap(),
        Event::Applied { sequence: 1, .. }
    ));
    let before = d.mirror().instance(1).unwrap().clone();
    assert_eq!(
        d.receive(&f3.bytes).unwrap(),
        Event::NeedKeyframe {
            have: Some(1),
            base: 2,
            sequence: 3
        }
    );
    assert_eq!(
        d.mirror().instance(1).unwrap(),
        &before,
        "a gap changes nothing"
    );
    let kf = s.keyframe();
    assert_eq!(kf.sequence, 3);
    assert_eq!(
        d.receive(&kf.bytes).unwrap(),
        Event::Applied {
            sequence: 3,
            keyframe: true
        }
    );
    assert_mirrors(&d, &s.table);
    let f4 = s.next();
    assert!(matches!(
        d.receive(&f4.bytes).unwrap(),
        Event::Applied { sequence: 4, .. }
    ));
    assert_mirrors(&d, &s.table);
}

#[test]
fn duplicates_and_reordered_old_frames_are_stale() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let f1 = s.next();
    let f2 = s.next();
    d.receive(&f1.bytes).unwrap();
    d.receive(&f2.bytes).unwrap();
    let state = d.mirror().instance(1).unwrap().clone();
    assert_eq!(
        d.receive(&f2.bytes).unwrap(),
        Event::Stale {
            sequence: 2,
            have: 2
        }
    );
    assert_eq!(
        d.receive(&f1.bytes).unwrap(),
        Event::Stale {
            sequence: 1,
            have: 2
        }
    );
    assert_eq!(d.mirror().instance(1).unwrap(), &state);
    assert_mirrors(&d, &s.table);
}

#[test]
fn reordered_newer_frame_then_older() {
    // f2 arrives before f1: f2 is a gap; f1 then applies; f2 again applies.
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let f1 = s.next();
    let f2 = s.next();
    assert!(matches!(
        d.receive(&f2.bytes).unwrap(),
        Event::NeedKeyframe { .. }
    ));
    assert!(matches!(
        d.receive(&f1.bytes).unwrap(),
        Event::Applied { sequence: 1, .. }
    ));
    assert!(matches!(
        d.receive(&f2.bytes).unwrap(),
        Event::Applied { sequence: 2, .. }
    ));
    assert_mirrors(&d, &s.table);
}

#[test]
fn sequence_wraps_around() {
    let mut s = Server::new(u32::MAX - 2);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let mut seen = Vec::new();
    for _ in 0..6 {
        let f = s.next();
        match d.receive(&f.bytes).unwrap() {
            Event::Applied { sequence, .. } => seen.push(sequence),
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(seen, [u32::MAX - 1, u32::MAX, 0, 1, 2, 3]);
    assert_mirrors(&d, &s.table);
    // A frame from before the wrap is stale, not newer.
    let mut old = Server::new(u32::MAX - 10);
    old.keyframe();
    let f = old.next();
    assert!(matches!(
        d.receive(&f.bytes).unwrap(),
        Event::Stale { .. } | Event::NeedKeyframe { .. }
    ));
    assert!(!sequence::is_newer(u32::MAX - 9, 3));
    assert!(sequence::is_newer(3, u32::MAX - 9));
}

#[test]
fn serial_comparison_is_rfc1982() {
    assert!(sequence::is_newer(1, 0));
    assert!(!sequence::is_newer(0, 0));
    assert!(sequence::is_newer(0, u32::MAX));
    assert!(
        !sequence::is_newer(1 << 31, 0),
        "exactly half way is not comparable"
    );
    assert!(!sequence::is_newer(0, 1 << 31));
    assert!(sequence::is_newer((1 << 31) - 1, 0));
}

#[test]
fn stale_keyframe_is_ignored() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    let old_kf = s.keyframe();
    d.receive(&old_kf.bytes).unwrap();
    s.next();
    s.next();
    d.receive(&s.keyframe().bytes).unwrap();
    assert_eq!(
        d.receive(&old_kf.bytes).unwrap(),
        Event::Stale {
            sequence: 0,
            have: 2
        }
    );
    assert_mirrors(&d, &s.table);
}

#[test]
fn keyframe_removes_instances_it_does_not_name() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let other = GridTable::new(2, small_def(), 8).unwrap();
    let kf = keyframe(&mut s.enc, &[&other]);
    d.receive(&kf.bytes).unwrap();
    assert!(d.mirror().instance(1).is_none());
    assert!(d.mirror().instance(2).is_some());
    assert!(d.mirror_mut().take_changes().all);
}

#[test]
fn late_transform_never_overwrites_newer() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    let m = |t: f32| [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, t, 0.0, 0.0];
    let mut f = s.enc.delta();
    f.transform(1, 10, &m(10.0));
    f.transform(1, 9, &m(9.0));
    d.receive(&f.finish().unwrap().unwrap().bytes).unwrap();
    assert_eq!(
        d.mirror()
            .instance(1)
            .unwrap()
            .transform()
            .unwrap()
            .sequence,
        10
    );
    // Out-of-frame transforms (e.g. datagrams) follow the same rule.
    let mirror = d.mirror_mut();
    assert!(
        !mirror
            .apply_transform(
                1,
                Transform {
                    sequence: 8,
                    matrix: m(8.0)
                }
            )
            .unwrap()
    );
    assert!(
        mirror
            .apply_transform(
                1,
                Transform {
                    sequence: 11,
                    matrix: m(11.0)
                }
            )
            .unwrap()
    );
    assert_eq!(
        mirror.instance(1).unwrap().transform().unwrap().matrix[9],
        11.0
    );
    assert_eq!(
        mirror.apply_transform(
            5,
            Transform {
                sequence: 1,
                matrix: m(0.0)
            }
        ),
        Err(MessageError::UnknownInstance(5))
    );
    let mut bad = m(0.0);
    bad[3] = f32::NAN;
    assert_eq!(
        mirror.apply_transform(
            1,
            Transform {
                sequence: 12,
                matrix: bad
            }
        ),
        Err(MessageError::NonFiniteTransform)
    );
}

#[test]
fn failing_message_rolls_back_the_whole_frame() {
    // A frame whose early messages are valid and whose last is not leaves
    // the mirror, its sequence and its change list exactly as they were.
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    for _ in 0..10 {
        d.receive(&s.next().bytes).unwrap();
    }
    d.mirror_mut().take_changes();
    let before = d.mirror().instance(1).unwrap().clone();
    for i in 0..20 {
        s.table
            .set_point(
                i,
                Vec3::new(-0.9 + i as f32 * 0.09, 0.5, 0.5),
                Vec3::X,
                0.25,
            )
            .unwrap();
    }
    let mut f = s.enc.delta();
    f.define_instance(77, &small_def()).unwrap();
    f.transform(
        1,
        3,
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    );
    f.changes(&mut s.table);
    f.remove_instance(1);
    f.remove_instance(1); // unknown by now: the frame fails here
    let frame = f.finish().unwrap().unwrap();
    let err = d.receive(&frame.bytes).unwrap_err();
    assert_eq!(err.code(), "unknown_instance");
    assert_eq!(d.mirror().instance(1).unwrap(), &before);
    assert!(d.mirror().instance(77).is_none());
    assert_eq!(d.mirror().sequence(), Some(10));
    assert_eq!(d.mirror_mut().take_changes(), Changes::default());
}

#[test]
fn mirror_reports_changed_ranges() {
    let mut s = Server::new(0);
    let mut d = Decoder::new(Limits::default());
    d.receive(&s.keyframe().bytes).unwrap();
    assert!(d.mirror_mut().take_changes().all);
    let f = s.next();
    d.receive(&f.bytes).unwrap();
    let changes = d.mirror_mut().take_changes();
    assert!(!changes.all);
    let cap = small_def().cell_capacity as u32;
    let words: Vec<_> = changes
        .items
        .iter()
        .filter_map(|c| match c {
            Change::Words(1, r) => Some(r.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(words, vec![0..cap], "the first point allocates cell 0");
    assert!(
        changes
            .items
            .iter()
            .any(|c| matches!(c, Change::Buckets(1, _)))
    );
}
