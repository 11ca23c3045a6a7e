//! A frame built over several calls ([`FrameBuilder::pause`] and
//! [`Encoder::resume`]) is the frame built in one go, and a paused frame
//! resumes only on the encoder and frame it came from.

mod common;

use common::*;
use glam::Vec3;
use psao_codec::*;

fn filled_table() -> GridTable {
    let mut table = GridTable::new(1, small_def(), 64).unwrap();
    for i in 0..10u32 {
        let x = i as f32 * 0.1 - 0.5;
        table
            .set_point(i, Vec3::new(x, 0.2, -0.1), Vec3::Y, i as f32 / 10.0)
            .unwrap();
    }
    table
}

#[test]
fn paused_and_resumed_frame_equals_one_built_at_once() {
    let matrix = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 3.0, 2.0, 1.0];

    let mut at_once = Encoder::new(EncoderConfig::default());
    let mut table = filled_table();
    let mut b = at_once.delta();
    b.define_instance(1, &small_def()).unwrap();
    b.transform(1, 1, &matrix);
    b.changes(&mut table);
    let expected = b.finish().unwrap().unwrap();

    let mut in_steps = Encoder::new(EncoderConfig::default());
    let mut table = filled_table();
    let mut b = in_steps.delta();
    b.define_instance(1, &small_def()).unwrap();
    let paused = b.pause();
    assert!(!paused.is_keyframe());
    assert_eq!(paused.messages(), 1);
    let mut b = in_steps.resume(paused).expect("same frame");
    b.transform(1, 1, &matrix);
    let paused = b.pause();
    let mut b = in_steps.resume(paused).expect("same frame");
    b.changes(&mut table);
    let got = b.pause();
    let got = in_steps.resume(got).unwrap().finish().unwrap().unwrap();

    assert_eq!(got, expected);
    assert_eq!(in_steps.sequence(), 1);
}

#[test]
fn a_paused_frame_is_refused_after_a_new_begin_or_by_another_encoder() {
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut b = enc.delta();
    b.remove_instance(3);
    let stale = b.pause();
    // A new frame begins: the paused one's messages are gone.
    let fresh = enc.keyframe().pause();
    assert!(enc.resume(stale).is_none());

    let mut other = Encoder::new(EncoderConfig::default());
    assert!(other.resume(fresh).is_none());
    assert_eq!(other.sequence(), 0);

    // The refusals changed nothing: a new delta still starts at sequence 1.
    let mut b = enc.delta();
    b.remove_instance(3);
    assert_eq!(b.finish().unwrap().unwrap().sequence, 1);
}

#[test]
fn an_abandoned_delta_with_messages_takes_its_sequence_so_clients_see_a_gap() {
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut table = filled_table();
    let mut b = enc.delta();
    b.define_instance(1, &small_def()).unwrap();
    b.changes(&mut table);
    let paused = b.pause();
    enc.abandon(paused);
    assert_eq!(enc.sequence(), 1);
    // An empty delta and a keyframe abandoned take nothing.
    let empty = enc.delta().pause();
    enc.abandon(empty);
    let kf = enc.keyframe().pause();
    enc.abandon(kf);
    assert_eq!(enc.sequence(), 1);
    // The next delta is 2, based on 1: a client at 0 needs a keyframe.
    let mut b = enc.delta();
    b.remove_instance(9);
    let frame = b.finish().unwrap().unwrap();
    assert_eq!(frame.sequence, 2);
    let mut dec = Decoder::new(Limits::default());
    let mut other = Encoder::new(EncoderConfig::default());
    let mut kf = other.keyframe();
    kf.snapshot(&GridTable::new(1, small_def(), 64).unwrap())
        .unwrap();
    dec.receive(&kf.finish().unwrap().unwrap().bytes).unwrap();
    assert!(matches!(
        dec.receive(&frame.bytes).unwrap(),
        Event::NeedKeyframe { base: 1, .. }
    ));
}
