//! The server's fan-out policy without sockets (spec/session.md 5.2): one
//! keyframe per state shared by all who ask, deltas to every client in
//! sync, a client that falls behind told so and resynchronized, bounded
//! notices, and what a culling server culls to.

use bytes::Bytes;
use glam::Vec3;
use psao_codec::{EncodedFrame, FrameStats};
use psao_proto::control::{CameraPose, Control, ControlReader, NoticeCode};
use psao_proto::fanout::MAX_NOTICES;
use psao_proto::{Fanout, Keyframes, Transmit};

fn frame(sequence: u32, keyframe: bool, len: usize) -> EncodedFrame {
    EncodedFrame {
        bytes: Bytes::from(vec![sequence as u8; len]),
        sequence,
        keyframe,
        stats: FrameStats::default(),
    }
}

fn notices(t: &Transmit) -> Vec<NoticeCode> {
    let mut reader = ControlReader::new();
    t.notices
        .iter()
        .map(|n| match reader.read(&mut &n[..]).unwrap() {
            Some(Control::Notice { code, .. }) => code,
            other => panic!("{other:?}"),
        })
        .collect()
}

/// A client that stays stalled drops its resync keyframe too when deltas
/// overflow behind it: it is told once, with the keyframe it finally
/// gets, not once per fall (issue 16: 32 notices for 2 resyncs before).
#[test]
fn a_stalled_client_is_told_once_per_keyframe_it_gets() {
    let mut f = Fanout::new(1024);
    let slow = f.add_client(false);
    f.serve_keyframes();
    f.push_keyframe(&frame(1, true, 50));
    f.poll_transmit(slow).unwrap();
    let mut seq = 2;
    for _ in 0..3 {
        // Falls, is given a keyframe, and falls again before writing it.
        while f.falls() == 0 || f.serve_keyframes() != Keyframes::Encode {
            f.push_frame(&frame(seq, false, 300));
            seq += 1;
        }
        f.push_keyframe(&frame(seq, true, 60));
    }
    assert!(f.falls() >= 3, "{}", f.falls());
    let mut got = Vec::new();
    while let Some(t) = f.poll_transmit(slow).filter(|t| t.frame.is_some()) {
        got.push((notices(&t), t.frame.unwrap()[0]));
    }
    assert_eq!(
        got,
        [(vec![NoticeCode::FellBehind], seq as u8)],
        "the last keyframe, with its notice"
    );
    assert_eq!(f.resyncs(), 1);
}

#[test]
fn one_keyframe_per_state_is_shared_by_all_who_ask() {
    let mut f = Fanout::new(1 << 20);
    let (a, b) = (f.add_client(false), f.add_client(false));
    // Both just joined: a keyframe is wanted and none is shared yet.
    assert!(f.wants_keyframe());
    assert_eq!(
        f.serve_keyframes(),
        Keyframes::Encode,
        "a keyframe must be encoded"
    );
    let kf = frame(1, true, 100);
    f.push_keyframe(&kf);
    assert!(!f.wants_keyframe());
    assert_eq!(f.serve_keyframes(), Keyframes::NotWanted);
    let (ta, tb) = (f.poll_transmit(a).unwrap(), f.poll_transmit(b).unwrap());
    let (fa, fb) = (ta.frame.unwrap(), tb.frame.unwrap());
    assert_eq!(fa, kf.bytes);
    assert_eq!(fa.as_ptr(), fb.as_ptr(), "the same bytes, not a copy");
    assert!(ta.notices.is_empty(), "joining is not falling behind");
    // A client asking before the next frame gets the shared keyframe: no
    // new one is encoded.
    let c = f.add_client(false);
    f.request_keyframe(a);
    assert_eq!(
        f.serve_keyframes(),
        Keyframes::Shared,
        "served from the shared keyframe"
    );
    assert_eq!(f.poll_transmit(c).unwrap().frame.unwrap(), kf.bytes);
    assert_eq!(f.poll_transmit(a).unwrap().frame.unwrap(), kf.bytes);
    // A frame moves the state on: deltas go to everyone, and the next
    // asker needs a new keyframe.
    let d = frame(2, false, 10);
    assert_eq!(f.push_frame(&d), 0);
    for id in [a, b, c] {
        assert_eq!(f.poll_transmit(id).unwrap().frame.unwrap(), d.bytes);
    }
    f.add_client(false);
    assert_eq!(
        f.serve_keyframes(),
        Keyframes::Encode,
        "the shared keyframe is out of date"
    );
}

#[test]
fn a_client_that_falls_behind_is_told_and_resynchronized() {
    let mut f = Fanout::new(1024);
    let (fast, slow) = (f.add_client(false), f.add_client(false));
    assert_eq!(f.serve_keyframes(), Keyframes::Encode);
    f.push_keyframe(&frame(1, true, 50));
    f.poll_transmit(fast).unwrap();
    f.poll_transmit(slow).unwrap();
    // The slow client drains nothing: its queue overflows.
    let mut fell = 0;
    for seq in 2..10 {
        fell += f.push_frame(&frame(seq, false, 300));
        let t = f.poll_transmit(fast).unwrap();
        assert_eq!(t.frame.unwrap()[0], seq as u8, "the fast client keeps up");
    }
    assert_eq!(fell, 1, "it falls once, then waits for a keyframe");
    assert_eq!(f.falls(), 1);
    assert!(f.max_queued_bytes() <= 1024);
    // Once it has drained, a keyframe is wanted; queued with a notice.
    while f.poll_transmit(slow).unwrap().frame.is_some() {}
    assert_eq!(f.serve_keyframes(), Keyframes::Encode);
    let kf = frame(9, true, 60);
    f.push_keyframe(&kf);
    let t = f.poll_transmit(slow).unwrap();
    assert_eq!(notices(&t), [NoticeCode::FellBehind]);
    assert_eq!(t.frame.unwrap(), kf.bytes);
    assert_eq!(
        f.poll_transmit(fast).unwrap().frame,
        None,
        "in sync: no keyframe"
    );
}

#[test]
fn notices_are_bounded_and_clients_come_and_go() {
    let mut f = Fanout::new(1 << 20);
    let a = f.add_client(false);
    for _ in 0..MAX_NOTICES + 5 {
        assert!(f.notice(a, NoticeCode::EventRefused, "no"));
    }
    assert_eq!(f.poll_transmit(a).unwrap().notices.len(), MAX_NOTICES);
    assert!(f.remove_client(a));
    assert!(!f.remove_client(a));
    assert!(!f.notice(a, NoticeCode::EventRefused, "gone"));
    assert_eq!(f.poll_transmit(a), None);
    assert!(f.is_empty() && !f.wants_keyframe());
    assert_eq!(f.serve_keyframes(), Keyframes::NotWanted);
    let b = f.add_client(false);
    assert_ne!(a, b, "ids are not reused");
}

#[test]
fn views_are_the_viewers_poses_unless_someone_does_not_say() {
    let pose = |x: f32| CameraPose {
        time_ms: 0,
        eye: Vec3::new(x, 1.0, 5.0),
        target: Vec3::ZERO,
        fov_y: 1.0,
        aspect: 1.5,
    };
    let mut f = Fanout::new(1 << 20);
    assert_eq!(f.views(), Some(vec![]), "no client: no one looks");
    let v = f.add_client(true);
    assert_eq!(f.views(), None, "a viewer without a CAMERA yet");
    f.set_view(v, pose(1.0));
    assert_eq!(f.views(), Some(vec![pose(1.0)]));
    let blind = f.add_client(false);
    f.set_view(blind, pose(2.0));
    assert_eq!(f.views(), None, "a non-viewer's poses do not count");
    f.remove_client(blind);
    assert_eq!(f.views(), Some(vec![pose(1.0)]));
}

/// A digest is wanted only when some client will get it: not for a
/// client waiting for a keyframe (deltas skip it), which used to make a
/// server compute one every tick while the client was behind.
#[test]
fn a_digest_is_wanted_only_for_a_client_that_will_get_it() {
    let mut f = Fanout::new(1 << 20);
    let c = f.add_client(false);
    f.set_digests(c, 1);
    // It waits for its first keyframe: deltas would be skipped.
    assert!(!f.wants_digest(false, None));
    assert!(f.wants_digest(true, None), "the keyframe it waits for");
    assert_eq!(f.serve_keyframes(), Keyframes::Encode);
    f.push_keyframe_with_digest(&frame(1, true, 50), Some(0xAB));
    let t = f.poll_transmit(c).unwrap();
    assert_eq!(t.notices.len(), 1, "the DIGEST goes before the keyframe");
    // In sync: every frame carries one (interval 1).
    assert!(f.wants_digest(false, None));
    // Asked while idle at the keyframe's state: answered at once. (The
    // test frames are filled with their sequence byte, so the header's
    // sequence field reads 0x01010101.)
    let at = 0x0101_0101;
    f.set_digests(c, 0);
    f.request_digest(c);
    assert!(!f.wants_digest(false, Some(2)), "not at the state it holds");
    assert!(f.wants_digest(false, Some(at)));
    assert_eq!(f.answer_digests(at, 0xCD), 1);
    assert!(!f.wants_digest(false, Some(at)), "answered");
}
