//! `WasmSession` natively, against psao-proto's own server session core:
//! HELLO answered by a `ServerConn`, frame records fed in pieces of every
//! size, the mirror at the encoder's state; a lost frame (the test hook)
//! makes it ask for a keyframe and leave sync until one comes; a bad
//! record length and bad control bytes give the spec's close codes; the
//! GPU buffers and the CPU reconstruction agree with psao-codec's.

use std::time::Instant;

use psao_codec::{
    Decoder, EncodedFrame, Encoder, EncoderConfig, GPU_RECORD_WORDS, Limits, Thresholds,
    reconstruct_ao,
};
use psao_proto::control::{Control, ControlReader, KeyframeReason};
use psao_proto::records::record_prefix;
use psao_proto::{CloseCode, Offer, ServerConn, ServerEvent};
use psao_tests::synthetic::Synthetic;
use psao_wasm::WasmSession;

fn record(f: &EncodedFrame) -> Vec<u8> {
    let mut r = record_prefix(&f.bytes).to_vec();
    r.extend_from_slice(&f.bytes);
    r
}

/// A welcomed session and the stream it follows.
fn welcomed() -> (WasmSession, Synthetic, Encoder) {
    let mut s = WasmSession::new();
    let hello = s.take_transmit().expect("HELLO is queued");
    let config = EncoderConfig::default();
    let offer = Offer {
        compression: config.compression.id(),
        max_frame_bytes: 1 << 24,
        max_payload_bytes: 1 << 24,
        largest_frame: 0,
        largest_payload: 0,
        mirror_bytes: 1 << 24,
        point_format: 0,
        overflow: false,
        frame_rate: 60,
        scene: "synthetic".into(),
        culling: false,
        digest: true,
    };
    let mut server = ServerConn::new(offer, Instant::now());
    let mut events = Vec::new();
    server
        .on_control(&hello, Instant::now(), &mut events)
        .unwrap();
    let Some(ServerEvent::Welcomed { bytes, .. }) = events.pop() else {
        panic!("no WELCOME: {events:?}");
    };
    assert!(!s.welcomed());
    s.on_control(&bytes).unwrap();
    assert!(s.welcomed() && s.frame_rate() == 60 && s.scene() == "synthetic");
    let mut scene = Synthetic::new(3);
    scene.table.take_dirty();
    (s, scene, Encoder::new(config))
}

/// The synthetic instance placed 2 m up x (so world and local differ).
const PLACED: [f32; 12] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0];

fn keyframe(enc: &mut Encoder, scene: &Synthetic) -> EncodedFrame {
    let mut kf = enc.keyframe();
    kf.snapshot(&scene.table).unwrap();
    kf.transform(1, 1, &PLACED);
    kf.finish().unwrap().unwrap()
}

fn delta(enc: &mut Encoder, scene: &mut Synthetic) -> EncodedFrame {
    loop {
        scene.step(&Thresholds::default());
        let mut d = enc.delta();
        d.changes(&mut scene.table);
        if let Some(f) = d.finish().unwrap() {
            return f;
        }
    }
}

#[test]
fn a_session_follows_a_stream_fed_in_pieces() {
    let (mut s, mut scene, mut enc) = welcomed();
    let mut reference = Decoder::new(Limits::default());
    let mut stream = Vec::new();
    let kf = keyframe(&mut enc, &scene);
    reference.receive(&kf.bytes).unwrap();
    stream.extend(record(&kf));
    for _ in 0..5 {
        let d = delta(&mut enc, &mut scene);
        reference.receive(&d.bytes).unwrap();
        stream.extend(record(&d));
    }
    // Pieces of 1 to 97 bytes.
    let (mut at, mut piece) = (0, 1);
    while at < stream.len() {
        let end = (at + piece).min(stream.len());
        s.on_frames(&stream[at..end]).unwrap();
        (at, piece) = (end, piece % 97 + 1);
    }
    assert_eq!(s.sequence(), reference.mirror().sequence());
    assert_eq!(s.digest(), reference.mirror().digest());
    assert!(s.in_sync());
    let st = s.stats();
    assert_eq!((st.applied, st.keyframes), (6.0, 1.0));
    assert_eq!(st.bytes, stream.len() as f64);
    // The keyframe was acknowledged.
    let sent = s.take_transmit().expect("an ACK");
    let msg = ControlReader::from(psao_proto::control::Sender::Client)
        .read(&mut &sent[..])
        .unwrap();
    assert!(matches!(msg, Some(Control::Ack(_))), "{msg:?}");

    // The GPU buffers: one record per id, every bucket and word.
    let m = reference.mirror();
    let inst = m.instance(1).unwrap();
    assert_eq!(s.gpu_instances().unwrap().len(), 2 * GPU_RECORD_WORDS);
    assert_eq!(s.gpu_words().unwrap(), inst.words());
    assert_eq!(s.gpu_buckets().unwrap().len(), 2 * inst.buckets().len());
    assert_eq!(s.transform(1), Some(PLACED.to_vec()));
    // The CPU reconstruction is psao-codec's, pixel for pixel, at a
    // point's place in the world.
    let (p, n, _) = scene.point(10);
    let p = p + glam::Vec3::X * 2.0;
    let ids = [1u32, 0xFFFF_FFFF, 7];
    let pos = [p.x, p.y, p.z, 0.0].repeat(3);
    let nrm = [n.x, n.y, n.z, 0.0].repeat(3);
    let ao = s.reconstruct(&pos, &nrm, &ids);
    let expected = match inst.transform() {
        None => 1.0,
        Some(t) => match psao_codec::world_to_local(&t.affine(), p, n) {
            Some((x, nl)) => reconstruct_ao(inst, x, nl),
            None => 1.0,
        },
    };
    assert!(expected < 1.0, "a point's own place is occluded a little");
    assert_eq!(ao, vec![expected, 1.0, 1.0]);
}

#[test]
fn a_lost_frame_asks_for_a_keyframe_and_one_brings_it_back() {
    let (mut s, mut scene, mut enc) = welcomed();
    s.on_frames(&record(&keyframe(&mut enc, &scene))).unwrap();
    let _ack = s.take_transmit();
    s.drop_next_frame();
    s.on_frames(&record(&delta(&mut enc, &mut scene))).unwrap();
    s.on_frames(&record(&delta(&mut enc, &mut scene))).unwrap();
    assert_eq!(s.stats().dropped_by_test, 1.0);
    assert!(!s.in_sync(), "a frame is missing");
    let sent = s.take_transmit().expect("KEYFRAME_REQUEST");
    let mut reader = ControlReader::from(psao_proto::control::Sender::Client);
    let mut input = &sent[..];
    let mut requested = false;
    while let Some(m) = reader.read(&mut input).unwrap() {
        requested |= matches!(
            m,
            Control::KeyframeRequest {
                reason: KeyframeReason::Gap,
                ..
            }
        );
    }
    assert!(requested);
    assert_eq!(s.stats().requests, 1.0);
    s.on_frames(&record(&keyframe(&mut enc, &scene))).unwrap();
    assert!(s.in_sync());
}

#[test]
fn bad_bytes_close_with_the_spec_codes() {
    let (mut s, _, _) = welcomed();
    // A record shorter than any frame.
    let e = s.on_frames(&[4, 0, 0, 0]).unwrap_err();
    assert_eq!(
        e.code(),
        CloseCode::ProtocolViolation.code(),
        "{}",
        e.reason()
    );
    let (mut s, _, _) = welcomed();
    // A control message of length 0.
    let e = s.on_control(&[0, 0]).unwrap_err();
    assert_eq!(
        e.code(),
        CloseCode::MessageTooLarge.code(),
        "{}",
        e.reason()
    );
    let e = WasmSession::new().on_control(&[1, 0, 0x7f]).unwrap_err();
    assert_eq!(
        e.code(),
        CloseCode::ProtocolViolation.code(),
        "{}",
        e.reason()
    );
}

#[test]
fn an_instance_id_past_the_pages_gpu_table_is_an_error_not_an_allocation() {
    let (mut s, _, mut enc) = welcomed();
    let big = psao_wasm::MAX_GPU_INSTANCE_ID + 1;
    let mut kf = enc.keyframe();
    kf.define_instance(big, &psao_tests::synthetic::def())
        .unwrap();
    s.on_frames(&record(&kf.finish().unwrap().unwrap()))
        .unwrap();
    assert!(s.sequence().is_some(), "the keyframe applied");
    let e = s.gpu_instances().unwrap_err();
    assert!(e.contains(&big.to_string()), "{e}");
    // The CPU reconstruction does not need the table.
    assert_eq!(
        s.reconstruct(&[0.0; 4], &[0.0, 1.0, 0.0, 0.0], &[big]),
        vec![1.0]
    );
}
