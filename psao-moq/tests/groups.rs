//! The sans-IO halves of spec/moq.md against each other: a `Broadcaster`
//! over a real pipeline (a box sliding over a floor) and `Follower`s fed
//! what it writes, whole, joined late, with frames or groups lost, and with
//! digests early or wrong.

use std::time::{Duration, Instant};

use bytes::Bytes;
use psao_codec::Limits;
use psao_moq::catalog::{decode_digest, encode_catalog, encode_digest};
use psao_moq::{Broadcaster, DigestCheck, FollowError, Followed, Follower, GroupPolicy, Write};
use psao_proto::control::Welcome;
use psao_proto::{FrameSource, SourceInfo};
use psao_scene::Pipeline;
use psao_tests::scenes::{pipeline, sliding_box};

/// A frame of the `frames` track, as a subscriber gets it.
#[derive(Clone, Debug)]
struct Got {
    group: u64,
    index: u64,
    bytes: Bytes,
}

/// What a run of the broadcaster wrote.
#[derive(Default)]
struct Run {
    frames: Vec<Got>,
    digests: Vec<Bytes>,
    writes: Vec<Write>,
}

fn welcome(info: &SourceInfo) -> Welcome {
    Welcome {
        version: 1,
        compression: info.compression,
        point_format: info.point_format,
        max_frame_bytes: info.max_frame_bytes,
        max_payload_bytes: info.max_payload_bytes,
        frame_rate: 60,
        culling: false,
        overflow: info.overflow,
        digest: true,
        scene: "sliding box".into(),
    }
}

fn source() -> Pipeline {
    pipeline(&sliding_box(), 64.0, 8)
}

/// Steps `source` `ticks` times, 1/60 s of the broadcaster's clock apart.
fn run(source: &mut Pipeline, b: &mut Broadcaster, ticks: usize, skip: &[usize]) -> Run {
    let t0 = Instant::now();
    let mut out = Run::default();
    let mut index = 0;
    for tick in 0..ticks {
        let now = t0 + Duration::from_secs_f64(tick as f64 / 60.0);
        let (frame, _) = FrameSource::step(source, 1.0 / 60.0).unwrap();
        // A skipped tick: the source encoded a delta nobody got.
        let frame = if skip.contains(&tick) { None } else { frame };
        let writes = b
            .step(now, frame, || FrameSource::keyframe(source))
            .unwrap();
        for w in writes {
            match &w {
                Write::Open { group, keyframe } => {
                    index = 0;
                    out.frames.push(Got {
                        group: *group,
                        index,
                        bytes: keyframe.clone(),
                    });
                }
                Write::Append { group, frame } => {
                    index += 1;
                    out.frames.push(Got {
                        group: *group,
                        index,
                        bytes: frame.clone(),
                    });
                }
                Write::Digest { body, .. } => out.digests.push(body.clone()),
            }
            out.writes.push(w);
        }
    }
    out
}

fn follower(info: &SourceInfo) -> Follower {
    let mut f = Follower::new(Limits::default());
    f.on_catalog(&encode_catalog(&welcome(info))).unwrap();
    f
}

#[test]
fn every_group_opens_with_a_keyframe_and_a_follower_matches_every_digest() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        max_age: Duration::from_millis(500),
        digest_every: 10,
        ..GroupPolicy::default()
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 120, &[]);
    let stats = b.stats();
    assert!(
        stats.groups >= 4,
        "2 s of groups at most 0.5 s old: {stats:?}"
    );
    assert!(stats.deltas > 0);
    // Group ids count from 0 by 1, and each opens with a keyframe.
    let mut expect = 0;
    for g in &r.frames {
        if g.index == 0 {
            assert_eq!(g.group, expect);
            assert_eq!(g.bytes[5] & 1, 1, "group {} opens with a keyframe", g.group);
            expect += 1;
        } else {
            assert_eq!(g.bytes[5] & 1, 0, "a delta inside group {}", g.group);
        }
    }
    // A follower fed everything in order: applied all, digests all match.
    let mut f = follower(&info);
    let mut matched = 0;
    let mut digests = r.digests.iter();
    let mut next = digests.next();
    for g in &r.frames {
        assert!(matches!(
            f.on_frame(g.group, g.index, &g.bytes),
            Followed::Applied { .. }
        ));
        while let Some(d) = next {
            let (seq, _) = decode_digest(d).unwrap();
            if Some(seq) != f.mirror().sequence() {
                break;
            }
            assert_eq!(f.on_digest(d).unwrap(), DigestCheck::Match);
            matched += 1;
            next = digests.next();
        }
        assert!(f.in_sync());
    }
    assert_eq!(matched, r.digests.len());
    assert!(
        matched as u64 >= stats.groups,
        "a digest for every keyframe at least"
    );
}

#[test]
fn groups_roll_over_at_the_byte_ratio_and_at_a_skipped_sequence() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        delta_ratio: 0.2,
        max_age: Duration::from_secs(3600),
        digest_every: 0,
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 90, &[40]);
    let st = b.stats();
    assert!(st.rolled_by_ratio > 0, "{st:?}");
    assert_eq!(st.rolled_by_age, 0);
    assert_eq!(
        st.rolled_by_gap, 1,
        "the tick after the skipped one: {st:?}"
    );
    assert!(r.digests.is_empty());
    // No group's deltas pass 0.2 times its keyframe.
    let mut key = 0usize;
    let mut deltas = 0usize;
    for g in &r.frames {
        if g.index == 0 {
            key = g.bytes.len();
            deltas = 0;
        } else {
            deltas += g.bytes.len();
            assert!(deltas as f64 <= 0.2 * key as f64);
        }
    }
    // And the stream still applies whole.
    let mut f = follower(&info);
    for g in &r.frames {
        assert!(matches!(
            f.on_frame(g.group, g.index, &g.bytes),
            Followed::Applied { .. }
        ));
    }
}

#[test]
fn a_still_scene_still_gets_a_keyframe_every_max_age() {
    // A floor alone: nothing changes after the first step.
    let mut scene = sliding_box();
    scene.animations.clear();
    let mut s = Pipeline::new(scene, psao_tests::scenes::pipeline_config(64.0, 8)).unwrap();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        max_age: Duration::from_millis(250),
        ..GroupPolicy::default()
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 61, &[]);
    // Ticks 0, 15, 30, 45, 60 (0.25 s apart at 60 Hz).
    assert_eq!(b.stats().groups, 5, "{:?}", b.stats());
    assert!(
        r.frames.iter().all(|g| g.index == 0),
        "no delta in a still scene"
    );
}

#[test]
fn a_late_joiner_waits_for_the_next_keyframe_then_follows() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        max_age: Duration::from_millis(500),
        digest_every: 0,
        ..GroupPolicy::default()
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 80, &[]);
    // Joins at the third frame of group 0.
    let mut f = follower(&info);
    let mut first_applied = None;
    for g in r.frames.iter().skip(3) {
        match f.on_frame(g.group, g.index, &g.bytes) {
            Followed::Applied { keyframe, .. } => {
                if first_applied.is_none() {
                    assert!(keyframe);
                    first_applied = Some(g.group);
                }
            }
            Followed::Ignored => assert!(first_applied.is_none()),
            other => panic!("{other:?} at group {} frame {}", g.group, g.index),
        }
    }
    assert_eq!(first_applied, Some(1));
    assert!(f.in_sync());
    let last = r.frames.last().unwrap();
    assert_eq!(
        f.mirror().sequence(),
        Some(u32::from_le_bytes(last.bytes[8..12].try_into().unwrap()))
    );
}

#[test]
fn a_lost_frame_or_group_waits_for_the_next_keyframe_and_an_old_group_is_ignored() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        max_age: Duration::from_millis(300),
        digest_every: 0,
        ..GroupPolicy::default()
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 100, &[]);
    let group = |id: u64| r.frames.iter().filter(move |g| g.group == id);
    let mut f = follower(&info);
    for g in group(0) {
        f.on_frame(g.group, g.index, &g.bytes);
    }
    // Group 1 loses its second frame: the rest wait.
    let g1: Vec<_> = group(1).collect();
    assert!(g1.len() > 3);
    f.on_frame(1, 0, &g1[0].bytes);
    assert_eq!(f.on_frame(1, 2, &g1[2].bytes), Followed::WaitKeyframe);
    assert!(!f.in_sync());
    assert_eq!(f.on_frame(1, 3, &g1[3].bytes), Followed::Ignored);
    // Group 2 is lost whole; group 3 repairs.
    for g in group(3) {
        assert!(matches!(
            f.on_frame(g.group, g.index, &g.bytes),
            Followed::Applied { .. }
        ));
    }
    assert!(f.in_sync());
    assert_eq!(f.stats().groups_missed, 1);
    // Group 2 arriving now is older than what the mirror holds.
    for g in group(2) {
        assert_eq!(f.on_frame(g.group, g.index, &g.bytes), Followed::Ignored);
    }
    assert!(f.in_sync());
}

#[test]
fn digests_wait_for_their_frame_and_a_wrong_one_holds_until_the_keyframe() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let policy = GroupPolicy {
        max_age: Duration::from_millis(300),
        digest_every: 5,
        ..GroupPolicy::default()
    };
    let mut b = Broadcaster::new(&info, policy);
    let r = run(&mut s, &mut b, 60, &[]);
    let mut f = follower(&info);
    // Every digest before any frame: held (the newest 8).
    for d in &r.digests {
        assert_eq!(f.on_digest(d).unwrap(), DigestCheck::Held);
    }
    for g in &r.frames {
        f.on_frame(g.group, g.index, &g.bytes);
    }
    let held = r.digests.len().min(psao_moq::HELD_DIGESTS) as u64;
    assert_eq!(f.stats().digests_matched, held, "{:?}", f.stats());
    assert!(f.in_sync());
    // A digest of the current sequence that does not match.
    let seq = f.mirror().sequence().unwrap();
    let good = f.mirror().digest().unwrap();
    assert_eq!(
        f.on_digest(&encode_digest(seq, good ^ 1)).unwrap(),
        DigestCheck::Mismatch
    );
    assert!(!f.in_sync());
    // One of a sequence the mirror passed.
    assert_eq!(
        f.on_digest(&encode_digest(seq.wrapping_sub(1), 0)).unwrap(),
        DigestCheck::Passed
    );
    // The next group's keyframe restores it.
    let mut more = run(&mut s, &mut b, 30, &[]).frames.into_iter();
    let next_key = more.find(|g| g.index == 0).unwrap();
    assert!(matches!(
        f.on_frame(next_key.group, 0, &next_key.bytes),
        Followed::Applied { keyframe: true, .. }
    ));
    assert!(f.in_sync());
}

#[test]
fn a_catalog_above_the_limits_or_one_that_changes_is_refused() {
    let info = FrameSource::info(&source());
    let w = welcome(&info);
    let small = Limits {
        max_frame_bytes: w.max_frame_bytes - 1,
        ..Limits::default()
    };
    let mut f = Follower::new(small);
    match f.on_catalog(&encode_catalog(&w)) {
        Err(FollowError::AboveLimits {
            what: "max_frame_bytes",
            ..
        }) => {}
        other => panic!("{other:?}"),
    }
    let mut f = Follower::new(Limits::default());
    f.on_catalog(&encode_catalog(&w)).unwrap();
    let changed = Welcome {
        frame_rate: 30,
        ..w.clone()
    };
    assert!(f.on_catalog(&encode_catalog(&changed)).is_err());
    // A new subscription may find another catalog (a publisher restarted).
    f.restart();
    assert!(f.on_catalog(&encode_catalog(&changed)).is_ok());
    f.restart();
    assert!(
        f.on_catalog(&encode_catalog(&w)).is_ok(),
        "the same catalog again"
    );
    // Frames and digests before a catalog.
    let mut f = Follower::new(Limits::default());
    assert!(matches!(
        f.on_digest(&encode_digest(1, 2)),
        Err(FollowError::BeforeCatalog(_))
    ));
    assert_eq!(f.on_frame(0, 0, &[0; 40]), Followed::Ignored);
}

#[test]
fn a_restart_discards_the_mirror_and_the_next_keyframe_rebuilds_it() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let mut b = Broadcaster::new(
        &info,
        GroupPolicy {
            max_age: Duration::from_millis(200),
            ..GroupPolicy::default()
        },
    );
    let r = run(&mut s, &mut b, 40, &[]);
    let mut f = follower(&info);
    for g in &r.frames {
        f.on_frame(g.group, g.index, &g.bytes);
    }
    let want = f.mirror().digest();
    f.restart();
    assert_eq!(f.mirror().sequence(), None);
    assert!(!f.in_sync());
    assert!(
        f.catalog().is_none(),
        "a new subscription reads the catalog anew"
    );
    f.on_catalog(&encode_catalog(&welcome(&info))).unwrap();
    // The relay hands the latest group again, from its keyframe.
    let last = r.frames.last().unwrap().group;
    for g in r.frames.iter().filter(|g| g.group == last) {
        f.on_frame(g.group, g.index, &g.bytes);
    }
    assert_eq!(f.mirror().digest(), want);
    assert!(f.in_sync());
}

#[test]
fn an_interrupted_group_is_followed_by_a_new_one_that_repairs_everyone() {
    let mut s = source();
    let info = FrameSource::info(&s);
    let mut b = Broadcaster::new(&info, GroupPolicy::default());
    let first = run(&mut s, &mut b, 10, &[]);
    assert_eq!(b.open_group(), Some(0));
    // A write of group 0 failed: the next step opens group 1.
    b.interrupt();
    assert_eq!(b.stats().interrupted, 1);
    let next = run(&mut s, &mut b, 5, &[]);
    assert_eq!(next.frames[0].group, 1);
    assert_eq!(next.frames[0].index, 0);
    // A subscriber that missed the end of group 0 follows from group 1.
    let mut f = follower(&info);
    for g in first.frames.iter().take(3).chain(&next.frames) {
        f.on_frame(g.group, g.index, &g.bytes);
    }
    assert!(f.in_sync());
}
