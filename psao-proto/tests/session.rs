//! The sans-IO session core: negotiation, the server's handshake deadline
//! and uplink rate, the bounded outbox, and the client's resync logic.

use std::time::{Duration, Instant};

use bytes::Bytes;
use glam::{Affine3A, Vec3};
use psao_codec::{
    Compression, Decoder, EncodedFrame, Encoder, EncoderConfig, GridTable, InstanceDef, Limits,
};
use psao_proto::control::{CameraPose, Control, Hello, KeyframeReason};
use psao_proto::*;

fn offer() -> Offer {
    Offer {
        compression: 2,
        max_frame_bytes: 1 << 20,
        max_payload_bytes: 1 << 20,
        largest_frame: 0,
        largest_payload: 0,
        mirror_bytes: 1 << 16,
        point_format: 0,
        overflow: false,
        frame_rate: 60,
        scene: "test".into(),
        culling: false,
        digest: false,
    }
}

/// The offer of a server encoding with lz4 (id 1), as `server()` does.
fn lz4_offer() -> Offer {
    Offer {
        compression: 1,
        ..offer()
    }
}

fn hello() -> Hello {
    Hello {
        version: 1,
        compressions: 0b111,
        point_formats: 1,
        max_frame_bytes: 1 << 20,
        max_payload_bytes: 1 << 20,
        max_mirror_bytes: 1 << 30,
        viewer: false,
        overflow: false,
        digest: false,
    }
}

#[test]
fn negotiation_refuses_what_the_client_cannot_take() {
    let w = negotiate(&hello(), &offer()).unwrap();
    assert_eq!(
        (w.compression, w.frame_rate, w.scene.as_str()),
        (2, 60, "test")
    );
    let code = |h: Hello| negotiate(&h, &offer()).unwrap_err().close_code();
    assert_eq!(
        code(Hello {
            compressions: 0b011,
            ..hello()
        }),
        CloseCode::CapabilityMismatch
    );
    // Limits below the server's cap are accepted while its frames fit
    // them (the spec's example HELLO offers 1 MiB); WELCOME says the
    // smaller of both.
    let small = Hello {
        max_frame_bytes: 65_536,
        max_payload_bytes: 1 << 19,
        ..hello()
    };
    let w = negotiate(&small, &offer()).unwrap();
    assert_eq!((w.max_frame_bytes, w.max_payload_bytes), (65_536, 1 << 19));
    // Below the largest frame sent so far: refused, naming its size.
    let sent = Offer {
        largest_frame: 70_000,
        largest_payload: 90_000,
        ..offer()
    };
    let e = negotiate(&small, &sent).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
    assert!(e.to_string().contains("70000"), "{e}");
    let e = negotiate(
        &Hello {
            max_payload_bytes: 80_000,
            ..hello()
        },
        &sent,
    )
    .unwrap_err();
    assert!(e.to_string().contains("90000 uncompressed"), "{e}");
    assert_eq!(
        code(Hello {
            max_mirror_bytes: 100,
            ..hello()
        }),
        CloseCode::CapabilityMismatch
    );
}

/// WELCOME's culling flag is set for a viewer of a culling server only: a
/// non-viewer is never culled for (issue 16's finding 4).
#[test]
fn only_a_viewer_is_told_that_the_server_culls() {
    let culling = Offer {
        culling: true,
        ..offer()
    };
    let viewer = Hello {
        viewer: true,
        ..hello()
    };
    assert!(negotiate(&viewer, &culling).unwrap().culling);
    assert!(!negotiate(&hello(), &culling).unwrap().culling);
    assert!(!negotiate(&viewer, &offer()).unwrap().culling);
}

/// Point format 1 (bind space): a server whose frames use it welcomes a
/// client that knows formats 0 and 1 with WELCOME.point_format 1 and
/// refuses one that knows only 0, naming the formats; a format-0 server
/// takes either. HELLO's and WELCOME's bytes carry the formats.
#[test]
fn point_format_one_is_negotiated() {
    let bind = Offer {
        point_format: 1,
        ..offer()
    };
    let both = Hello {
        point_formats: 0b11,
        ..hello()
    };
    assert_eq!(negotiate(&both, &bind).unwrap().point_format, 1);
    assert_eq!(negotiate(&both, &offer()).unwrap().point_format, 0);
    assert_eq!(negotiate(&hello(), &offer()).unwrap().point_format, 0);
    let e = negotiate(&hello(), &bind).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
    assert!(e.to_string().contains("point formats 0 to 1"), "{e}");
    // The bytes: HELLO with bits 0 and 1 reads back; bit 2 is reserved.
    let mut b = bytes(Control::Hello(both)).to_vec();
    let mut r = psao_proto::control::ControlReader::new();
    let mut input = &b[..];
    assert_eq!(r.read(&mut input).unwrap(), Some(Control::Hello(both)));
    b[2 + 1 + 7] |= 0b100;
    let mut input = &b[..];
    assert!(
        psao_proto::control::ControlReader::new()
            .read(&mut input)
            .is_err()
    );
    // WELCOME with point format 1 reads back; 2 is out of range.
    let w = negotiate(
        &Hello {
            point_formats: 0b11,
            ..hello()
        },
        &bind,
    )
    .unwrap();
    let mut b = bytes(Control::Welcome(w.clone())).to_vec();
    let mut input = &b[..];
    assert_eq!(
        psao_proto::control::ControlReader::new()
            .read(&mut input)
            .unwrap(),
        Some(Control::Welcome(w))
    );
    b[2 + 1 + 3] = 2;
    let mut input = &b[..];
    assert!(
        psao_proto::control::ControlReader::new()
            .read(&mut input)
            .is_err()
    );
}

/// A client that cannot draw bind-space instances offers point format 0
/// alone, and closes on a WELCOME that chose format 1 anyway.
#[test]
fn a_client_may_offer_point_format_0_alone() {
    let mut both = ClientSession::new(ClientConfig::default());
    assert_eq!(hello_of(&mut both).point_formats, 0b11);
    let mut only = ClientSession::new(ClientConfig {
        point_format_0_only: true,
        ..ClientConfig::default()
    });
    let h = hello_of(&mut only);
    assert_eq!(h.point_formats, 0b01);
    let bind = Offer {
        point_format: 1,
        ..offer()
    };
    assert_eq!(
        negotiate(&h, &bind).unwrap_err().close_code(),
        CloseCode::CapabilityMismatch
    );
    let mut w = negotiate(&h, &offer()).unwrap();
    w.point_format = 1;
    let e = only.on_control(&bytes(Control::Welcome(w))).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
}

/// Overflow chains (spec/wire-format.md 7.4) are negotiated by HELLO's and
/// WELCOME's flags bit 1: a server whose frames use them refuses a client
/// that did not offer them, naming them, and tells one that did; a client
/// closes on a WELCOME announcing chains it did not offer. Bit 2 stays
/// reserved.
#[test]
fn overflow_chains_are_negotiated() {
    let chained = Offer {
        overflow: true,
        ..offer()
    };
    let offers = Hello {
        overflow: true,
        ..hello()
    };
    assert!(negotiate(&offers, &chained).unwrap().overflow);
    assert!(!negotiate(&offers, &offer()).unwrap().overflow);
    let e = negotiate(&hello(), &chained).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
    assert!(e.to_string().contains("overflow chains"), "{e}");
    // The bytes: flags bit 1 reads back; bit 3 is reserved (bit 2 is
    // `digest`).
    let mut b = bytes(Control::Hello(offers)).to_vec();
    let mut input = &b[..];
    assert_eq!(
        psao_proto::control::ControlReader::new()
            .read(&mut input)
            .unwrap(),
        Some(Control::Hello(offers))
    );
    let last = b.len() - 1;
    b[last] |= 0b1000;
    let mut input = &b[..];
    assert!(
        psao_proto::control::ControlReader::new()
            .read(&mut input)
            .is_err()
    );
    // A client offers chains by default; one that does not closes on a
    // WELCOME with them.
    assert!(hello_of(&mut ClientSession::new(ClientConfig::default())).overflow);
    let mut flat = ClientSession::new(ClientConfig {
        no_overflow: true,
        ..ClientConfig::default()
    });
    let h = hello_of(&mut flat);
    assert!(!h.overflow);
    let mut w = negotiate(&h, &offer()).unwrap();
    w.overflow = true;
    let e = flat.on_control(&bytes(Control::Welcome(w))).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
}

fn bytes(c: Control) -> Bytes {
    c.to_bytes().freeze()
}

#[test]
fn the_server_wants_hello_first_once_and_in_time() {
    let t0 = Instant::now();
    let mut events = Vec::new();
    // Anything before HELLO.
    let mut s = ServerConn::new(offer(), t0);
    let e = s
        .on_control(&bytes(Control::Ack(3)), t0, &mut events)
        .unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
    // HELLO, then WELCOME comes out; a second HELLO is a violation.
    let mut s = ServerConn::new(offer(), t0);
    s.on_control(&bytes(Control::Hello(hello())), t0, &mut events)
        .unwrap();
    assert!(matches!(
        events.pop(),
        Some(ServerEvent::Welcomed { viewer: false, .. })
    ));
    let e = s
        .on_control(&bytes(Control::Hello(hello())), t0, &mut events)
        .unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
    // A wrong version.
    let mut s = ServerConn::new(offer(), t0);
    let e = s
        .on_control(
            &bytes(Control::Hello(Hello {
                version: 2,
                ..hello()
            })),
            t0,
            &mut events,
        )
        .unwrap_err();
    assert_eq!(e.close_code(), CloseCode::VersionMismatch);
    // Too late.
    let s = ServerConn::new(offer(), t0);
    assert!(s.on_timer(t0 + Duration::from_secs(4)).is_ok());
    assert_eq!(
        s.on_timer(t0 + Duration::from_secs(5))
            .unwrap_err()
            .close_code(),
        CloseCode::HandshakeTimeout
    );
    // A camera from a client that did not say it is a viewer.
    let mut s = ServerConn::new(offer(), t0);
    s.on_control(&bytes(Control::Hello(hello())), t0, &mut events)
        .unwrap();
    let cam = CameraPose {
        time_ms: 0,
        eye: Vec3::Z,
        target: Vec3::ZERO,
        fov_y: 1.0,
        aspect: 1.5,
    };
    let e = s
        .on_control(&bytes(Control::Camera(cam)), t0, &mut events)
        .unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
}

#[test]
fn the_uplink_rate_is_bounded() {
    let t0 = Instant::now();
    let mut events = Vec::new();
    let mut s = ServerConn::new(offer(), t0);
    s.on_control(&bytes(Control::Hello(hello())), t0, &mut events)
        .unwrap();
    // 255 more messages in the same instant fit the bucket of 256...
    let mut burst = Vec::new();
    for k in 0..255 {
        burst.extend_from_slice(&bytes(Control::Ack(k)));
    }
    s.on_control(&burst, t0, &mut events).unwrap();
    // ...the next does not, until time refills it.
    let one = bytes(Control::Ack(9));
    let mut again = ServerConn::new(offer(), t0);
    let mut all = bytes(Control::Hello(hello())).to_vec();
    all.extend_from_slice(&burst);
    all.extend_from_slice(&one);
    let e = again.on_control(&all, t0, &mut events).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::RateExceeded);
    assert!(
        s.on_control(&one, t0 + Duration::from_millis(10), &mut events)
            .is_ok()
    );
}

#[test]
fn the_outbox_is_bounded_and_resyncs_with_a_keyframe() {
    let mut o = Outbox::new(1000);
    assert!(o.wants_keyframe(), "a new client waits for a keyframe");
    assert_eq!(o.push_delta(Bytes::from(vec![0; 100])), Pushed::Skipped);
    assert!(!o.push_keyframe(Bytes::from(vec![1; 300])));
    // The bound is on deltas: 1000 bytes of them behind the keyframe.
    for _ in 0..10 {
        assert_eq!(o.push_delta(Bytes::from(vec![2; 100])), Pushed::Queued);
    }
    assert_eq!(o.queued_bytes(), 1300);
    // The reader stalls: the next delta does not fit.
    assert_eq!(o.push_delta(Bytes::from(vec![3; 100])), Pushed::FellBehind);
    assert_eq!(o.queued_bytes(), 0);
    assert!(o.is_behind() && o.wants_keyframe());
    assert_eq!(o.push_delta(Bytes::from(vec![4; 100])), Pushed::Skipped);
    assert!(
        o.push_keyframe(Bytes::from(vec![5; 300])),
        "it had fallen behind"
    );
    assert!(!o.is_behind());
    assert_eq!(o.pop().unwrap()[0], 5);
    assert_eq!(o.falls(), 1);
    // However long the stall, the queue never holds more than the bound
    // plus one keyframe.
    let mut most = 0;
    for k in 0..10_000u32 {
        if o.wants_keyframe() {
            o.push_keyframe(Bytes::from(vec![6; 300]));
        }
        o.push_delta(Bytes::from(vec![7; 10 + (k % 200) as usize]));
        most = most.max(o.queued_bytes());
    }
    assert!(most <= 1000 + 300, "{most}");
    // A keyframe larger than the bound does not make the next deltas
    // overflow: the bound is on the deltas queued behind it.
    let mut o = Outbox::new(1000);
    o.push_keyframe(Bytes::from(vec![1; 5000]));
    for _ in 0..10 {
        assert_eq!(o.push_delta(Bytes::from(vec![2; 100])), Pushed::Queued);
    }
    assert_eq!(o.queued_bytes(), 6000);
    assert_eq!(o.push_delta(Bytes::from(vec![3; 100])), Pushed::FellBehind);
    // A request while a keyframe waits is answered by that keyframe.
    let mut o = Outbox::new(1000);
    o.push_keyframe(Bytes::from(vec![1; 10]));
    o.request_keyframe();
    assert_eq!(o.push_delta(Bytes::from(vec![2; 10])), Pushed::Queued);
    // A requested keyframe waits until the queue ahead of it has drained.
    let mut o = Outbox::new(1000);
    o.push_keyframe(Bytes::from(vec![1; 10]));
    o.push_delta(Bytes::from(vec![2; 10]));
    o.pop();
    o.request_keyframe();
    assert!(!o.wants_keyframe());
    o.pop();
    assert!(o.wants_keyframe());
}

/// A one-instance server table and encoder, for driving a client session.
fn server() -> (GridTable, Encoder) {
    let def = InstanceDef {
        origin: Vec3::ZERO,
        cell_size: Vec3::splat(0.5),
        dims: glam::UVec3::splat(8),
        table_log2: 6,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 128,
        point_format: 0,
        overflow: false,
        radius: 0.1,
        t_n: 0.1,
        t_d: 0.7,
    };
    let table = GridTable::new(0, def, 64).unwrap();
    let enc = Encoder::new(EncoderConfig {
        compression: Compression::Lz4,
        ..EncoderConfig::default()
    });
    (table, enc)
}

#[test]
fn the_client_acks_asks_for_one_keyframe_on_a_gap_and_resyncs() {
    let (mut table, mut enc) = server();
    let mut c = ClientSession::new(ClientConfig::default());
    let hello = hello_of(&mut c);
    // Frames before WELCOME are fine (streams race), but nothing but HELLO
    // goes out before it.
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let kf = kf.finish().unwrap().unwrap();
    let record = |b: &[u8]| {
        let mut r = (b.len() as u32).to_le_bytes().to_vec();
        r.extend_from_slice(b);
        r
    };
    c.on_frames(&record(&kf.bytes)).unwrap();
    assert!(matches!(
        c.poll_event(),
        Some(ClientEvent::Applied { keyframe: true, .. })
    ));
    assert!(c.take_transmit().is_none(), "no ACK before WELCOME");
    // The server encodes with lz4 (id 1).
    let welcome = negotiate(&hello, &lz4_offer()).unwrap();
    c.on_control(&bytes(Control::Welcome(welcome))).unwrap();
    assert!(matches!(c.poll_event(), Some(ClientEvent::Welcomed(_))));
    // Three deltas; the client misses the second.
    let mut deltas = Vec::new();
    for k in 0..3u32 {
        table
            .set_point(k, Vec3::splat(1.0 + k as f32 * 0.5), Vec3::Y, 0.5)
            .unwrap();
        let mut d = enc.delta();
        d.changes(&mut table);
        deltas.push(d.finish().unwrap().unwrap());
    }
    c.on_frames(&record(&deltas[0].bytes)).unwrap();
    c.on_frames(&record(&deltas[2].bytes)).unwrap();
    c.on_frames(&record(&deltas[2].bytes)).unwrap();
    let events: Vec<_> = std::iter::from_fn(|| c.poll_event()).collect();
    assert!(matches!(
        events[0],
        ClientEvent::Applied {
            keyframe: false,
            ..
        }
    ));
    assert!(matches!(events[1], ClientEvent::Gap { .. }));
    // The first delta after WELCOME is acknowledged (then about 10 a
    // second at 60 Hz: every 6th), and one request goes out for two gaps.
    let sent = c.take_transmit().unwrap();
    // The keyframe applied before WELCOME is acknowledged when WELCOME
    // comes (issue 16's conformance kit found it never was).
    let want_kf_ack = bytes(Control::Ack(kf.sequence));
    let want_ack = bytes(Control::Ack(deltas[0].sequence));
    let want_req = bytes(Control::KeyframeRequest {
        sequence: deltas[0].sequence,
        reason: KeyframeReason::Gap,
    });
    assert_eq!(
        &sent[..],
        [&want_kf_ack[..], &want_ack[..], &want_req[..]].concat(),
        "one request for two gaps"
    );
    assert_eq!(c.stats().requests, 1);
    // A corrupt frame leaves the mirror as it was.
    let before = c.mirror().instance(0).unwrap().words().to_vec();
    let mut bad = deltas[2].bytes.to_vec();
    bad[40] ^= 0xFF;
    c.on_frames(&record(&bad)).unwrap();
    assert_eq!(c.mirror().instance(0).unwrap().words(), &before[..]);
    // The keyframe resyncs it to the server's table.
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let kf = kf.finish().unwrap().unwrap();
    c.on_frames(&record(&kf.bytes)).unwrap();
    assert_eq!(c.mirror().instance(0).unwrap().words(), table.words());
    // A record longer than the client accepts closes the session.
    let mut c = ClientSession::new(ClientConfig {
        limits: Limits {
            max_frame_bytes: 65_536,
            ..Limits::default()
        },
        ..ClientConfig::default()
    });
    let e = c.on_frames(&(70_000u32).to_le_bytes()).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
    // So does a WELCOME that picks what HELLO did not offer, or a second one.
    let mut c = ClientSession::new(ClientConfig::default());
    let mut w = negotiate(&hello_of(&mut c), &offer()).unwrap();
    w.max_frame_bytes = u32::MAX;
    assert_eq!(
        c.on_control(&bytes(Control::Welcome(w)))
            .unwrap_err()
            .close_code(),
        CloseCode::CapabilityMismatch
    );
}

fn hello_of(c: &mut ClientSession) -> Hello {
    let b = c.take_transmit().unwrap();
    match Control::decode(b[2], &b[3..]).unwrap() {
        Control::Hello(h) => h,
        other => panic!("{other:?}"),
    }
}

#[test]
fn move_requests_and_cameras_leave_the_client_as_specified() {
    let mut c = ClientSession::new(ClientConfig {
        viewer: true,
        ..ClientConfig::default()
    });
    c.take_transmit();
    let t = Affine3A::from_translation(Vec3::X);
    c.send_move(4, t);
    let pose = CameraPose {
        time_ms: 5,
        eye: Vec3::Z,
        target: Vec3::ZERO,
        fov_y: 1.0,
        aspect: 2.0,
    };
    assert!(c.send_camera(pose));
    let sent = c.take_transmit().unwrap();
    let want = [
        bytes(Control::MoveInstance {
            instance: 4,
            transform: t,
        }),
        bytes(Control::Camera(pose)),
    ]
    .concat();
    assert_eq!(&sent[..], &want[..]);
    let mut not_viewer = ClientSession::new(ClientConfig::default());
    assert!(!not_viewer.send_camera(pose));
}

/// A client that has its WELCOME (compression lz4, as `server()` encodes).
fn welcomed() -> ClientSession {
    let mut c = ClientSession::new(ClientConfig::default());
    let hello = hello_of(&mut c);
    let welcome = negotiate(&hello, &lz4_offer()).unwrap();
    c.on_control(&bytes(Control::Welcome(welcome))).unwrap();
    assert!(matches!(c.poll_event(), Some(ClientEvent::Welcomed(_))));
    c
}

/// Takes the table's pending changes (a keyframe snapshot needs none).
fn settle(table: &mut GridTable) {
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut d = enc.delta();
    d.changes(table);
    let _ = d.finish().unwrap();
}

fn record(b: &[u8]) -> Vec<u8> {
    let mut r = (b.len() as u32).to_le_bytes().to_vec();
    r.extend_from_slice(b);
    r
}

#[test]
fn a_frame_in_a_compression_welcome_did_not_choose_is_a_decode_failure() {
    let (mut table, _) = server();
    table.set_point(0, Vec3::splat(1.0), Vec3::Y, 0.5).unwrap();
    settle(&mut table);
    let mut c = welcomed();
    // zstd, while WELCOME chose lz4.
    let mut zstd = Encoder::new(EncoderConfig {
        compression: Compression::Zstd,
        ..EncoderConfig::default()
    });
    let mut kf = zstd.keyframe();
    kf.snapshot(&table).unwrap();
    let kf = kf.finish().unwrap().unwrap();
    assert_eq!(kf.bytes[6], 2, "the header says zstd");
    c.on_frames(&record(&kf.bytes)).unwrap();
    assert_eq!(
        c.poll_event(),
        Some(ClientEvent::WrongCompression {
            sequence: kf.sequence,
            compression: 2
        })
    );
    assert!(c.mirror().instance(0).is_none(), "not applied");
    assert_eq!(c.stats().failed, 1);
    let sent = c.take_transmit().unwrap();
    assert_eq!(
        &sent[..],
        &bytes(Control::KeyframeRequest {
            sequence: 0,
            reason: KeyframeReason::NoState
        })[..]
    );
    // A second keyframe in a row that cannot be decoded ends the session.
    let e = c.on_frames(&record(&kf.bytes)).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch, "{e:?}");
}

#[test]
fn two_corrupt_keyframes_in_a_row_close_but_one_does_not() {
    let (mut table, mut enc) = server();
    table.set_point(0, Vec3::splat(1.0), Vec3::Y, 0.5).unwrap();
    settle(&mut table);
    let mut c = welcomed();
    let keyframe = |enc: &mut Encoder| {
        let mut kf = enc.keyframe();
        kf.snapshot(&table).unwrap();
        kf.finish().unwrap().unwrap()
    };
    let corrupt = |b: &[u8]| {
        let mut b = b.to_vec();
        let last = b.len() - 1;
        b[last] ^= 0xFF;
        b
    };
    let kf = keyframe(&mut enc);
    c.on_frames(&record(&corrupt(&kf.bytes))).unwrap();
    assert!(matches!(c.poll_event(), Some(ClientEvent::DecodeFailed(_))));
    // A good keyframe in between resets the count.
    let kf = keyframe(&mut enc);
    c.on_frames(&record(&kf.bytes)).unwrap();
    let kf = keyframe(&mut enc);
    c.on_frames(&record(&corrupt(&kf.bytes))).unwrap();
    let kf = keyframe(&mut enc);
    let e = c.on_frames(&record(&corrupt(&kf.bytes))).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::CapabilityMismatch);
    assert!(
        matches!(e, SessionError::KeyframesFailed { failed: 2 }),
        "{e:?}"
    );
}

#[test]
fn an_unanswered_request_is_repeated_after_two_seconds_without_frames() {
    let (mut table, mut enc) = server();
    let mut c = welcomed();
    // A delta whose base the client never saw: one request.
    table.set_point(0, Vec3::splat(1.0), Vec3::Y, 0.5).unwrap();
    settle(&mut table);
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let _lost = kf.finish().unwrap().unwrap();
    table.set_point(1, Vec3::splat(2.0), Vec3::Y, 0.5).unwrap();
    let mut d = enc.delta();
    d.changes(&mut table);
    let delta = d.finish().unwrap().unwrap();
    c.on_frames(&record(&delta.bytes)).unwrap();
    let first = c.take_transmit().unwrap();
    let t0 = Instant::now();
    // Then nothing comes (a still scene sends no frames). The session
    // says when it needs waking: now, to stamp the request, then when
    // the retry is due.
    c.handle_timeout(t0).unwrap();
    assert_eq!(c.poll_timeout(), Some(t0 + REQUEST_RETRY));
    c.handle_timeout(t0 + Duration::from_millis(1900)).unwrap();
    assert!(c.take_transmit().is_none(), "not yet");
    c.handle_timeout(t0 + REQUEST_RETRY).unwrap();
    let again = c.take_transmit().expect("the request is repeated");
    assert_eq!(again, first, "the same request, same reason");
    assert_eq!(c.stats().requests, 2);
    // Once a keyframe is applied, time alone sends nothing.
    settle(&mut table);
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    c.on_frames(&record(&kf.finish().unwrap().unwrap().bytes))
        .unwrap();
    let _ack = c.take_transmit();
    assert_eq!(c.poll_timeout(), None, "nothing waits on time");
    c.handle_timeout(t0 + 10 * REQUEST_RETRY).unwrap();
    c.handle_timeout(t0 + 20 * REQUEST_RETRY).unwrap();
    assert!(c.take_transmit().is_none());
}

#[test]
fn a_close_that_never_follows_the_finished_frame_stream_ends_the_session() {
    let mut c = welcomed();
    let t0 = Instant::now();
    c.handle_timeout(t0).unwrap();
    assert_eq!(c.poll_timeout(), None);
    assert_eq!(
        c.transport_lost("timed out").close_code(),
        CloseCode::InternalError,
        "before the frame stream finished, a lost link is an error"
    );
    // The server finishes its frames (it is shutting down); its close is
    // due within about a second (spec/session.md 5.3).
    c.on_frames_finished(t0);
    assert!(c.frames_finished());
    assert_eq!(c.poll_timeout(), Some(t0 + CLOSE_AFTER_FRAMES));
    assert_eq!(
        c.transport_lost("timed out").close_code(),
        CloseCode::ServerShutdown,
        "after it, a lost close is the shutdown it announced"
    );
    c.handle_timeout(t0 + CLOSE_AFTER_FRAMES - Duration::from_millis(1))
        .unwrap();
    let e = c.handle_timeout(t0 + CLOSE_AFTER_FRAMES).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ServerShutdown, "{e}");
}

#[test]
fn the_client_decodes_with_the_limits_its_hello_offers() {
    // Configured below the 65,536 bytes HELLO must offer: HELLO offers
    // 65,536, and frames within that decode.
    let mut c = ClientSession::new(ClientConfig {
        limits: Limits {
            max_frame_bytes: 64,
            max_payload_bytes: 64,
            ..Limits::default()
        },
        ..ClientConfig::default()
    });
    let hello = hello_of(&mut c);
    assert_eq!(
        (hello.max_frame_bytes, hello.max_payload_bytes),
        (65_536, 65_536)
    );
    let welcome = negotiate(
        &hello,
        &Offer {
            max_frame_bytes: 65_536,
            max_payload_bytes: 65_536,
            ..lz4_offer()
        },
    )
    .unwrap();
    c.on_control(&bytes(Control::Welcome(welcome))).unwrap();
    let (mut table, mut enc) = server();
    for k in 0..40 {
        table
            .set_point(k, Vec3::new(0.1 * k as f32, 1.0, 1.0), Vec3::Y, 0.5)
            .unwrap();
    }
    settle(&mut table);
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let kf = kf.finish().unwrap().unwrap();
    assert!(kf.bytes.len() > 64, "{} bytes", kf.bytes.len());
    c.on_frames(&record(&kf.bytes)).unwrap();
    assert_eq!(c.stats().failed, 0);
    assert!(c.mirror().instance(0).is_some(), "the keyframe applied");
}

/// Mirror digests on the client (spec/session.md 3.8): a `DIGEST` for
/// the mirror's sequence is checked at once, one for a later sequence
/// when the mirror reaches it, one the mirror has passed is dropped; a
/// wrong one asks for a keyframe with reason 4, and the keyframe repairs
/// the mirror (a negative control: a digest off by one bit).
#[test]
fn the_client_checks_digests_and_asks_for_a_keyframe_on_a_mismatch() {
    let (mut table, mut enc) = server();
    let mut c = ClientSession::new(ClientConfig::default());
    let hello = hello_of(&mut c);
    assert!(hello.digest, "the reference client offers digests");
    let offer = Offer {
        digest: true,
        ..lz4_offer()
    };
    let welcome = negotiate(&hello, &offer).unwrap();
    assert!(welcome.digest);
    c.on_control(&bytes(Control::Welcome(welcome))).unwrap();
    let record = |b: &[u8]| [&(b.len() as u32).to_le_bytes()[..], b].concat();
    // The server's mirror of its own stream gives the digests.
    let mut own = Decoder::new(Limits::default());
    let mut serve = |f: &EncodedFrame| {
        own.receive(&f.bytes).unwrap();
        (f.sequence, own.mirror().digest().unwrap())
    };
    let mut kf = enc.keyframe();
    kf.snapshot(&table).unwrap();
    let kf = kf.finish().unwrap().unwrap();
    let (s0, d0) = serve(&kf);
    c.on_frames(&record(&kf.bytes)).unwrap();
    let digest = |sequence, digest| bytes(Control::Digest { sequence, digest });
    // At the mirror's sequence: checked at once.
    c.on_control(&digest(s0, d0)).unwrap();
    assert_eq!(c.stats().digests_matched, 1);
    let mut delta = |table: &mut GridTable, k: u32| {
        table
            .set_point(k, Vec3::splat(1.0 + k as f32 * 0.5), Vec3::Y, 0.5)
            .unwrap();
        let mut d = enc.delta();
        d.changes(table);
        d.finish().unwrap().unwrap()
    };
    // For the next frame, before it arrives: checked when it applies.
    let f1 = delta(&mut table, 0);
    let (s1, d1) = serve(&f1);
    assert_ne!(d1, d0, "the state changed, so did the digest");
    c.on_control(&digest(s1, d1)).unwrap();
    assert_eq!(c.stats().digests_matched, 1, "not yet at {s1}");
    c.on_frames(&record(&f1.bytes)).unwrap();
    assert_eq!(c.stats().digests_matched, 2);
    // One for a state the mirror has passed is dropped.
    c.on_control(&digest(s0, d0)).unwrap();
    assert_eq!(c.stats().digests_dropped, 1);
    assert_eq!(c.stats().digest_mismatches, 0);
    let _ = c.take_transmit();
    // One bit off: a mismatch, and a keyframe request with reason 4.
    c.on_control(&digest(s1, d1 ^ 1)).unwrap();
    assert_eq!(c.stats().digest_mismatches, 1);
    let sent = c.take_transmit().expect("a keyframe request");
    assert_eq!(
        &sent[..],
        &bytes(Control::KeyframeRequest {
            sequence: s1,
            reason: KeyframeReason::DigestMismatch,
        })[..]
    );
    let events: Vec<_> = std::iter::from_fn(|| c.poll_event()).collect();
    assert!(events.contains(&ClientEvent::DigestChecked {
        sequence: s1,
        matched: false
    }));
}

/// The server side of digests: `DIGEST_REQUEST` and reason 4 are taken
/// only in a session that negotiated digests, else `protocol_violation`.
#[test]
fn digest_messages_need_a_digest_session() {
    let now = Instant::now();
    let run = |offer: Offer, hello: Hello, msg: Control| {
        let mut s = ServerConn::new(offer, now);
        let mut events = Vec::new();
        s.on_control(&bytes(Control::Hello(hello)), now, &mut events)
            .unwrap();
        let r = s.on_control(&bytes(msg), now, &mut events);
        (r, events)
    };
    let digests = Offer {
        digest: true,
        ..offer()
    };
    let asks = Hello {
        digest: true,
        ..hello()
    };
    let request = Control::DigestRequest { every: 10 };
    let mismatch = Control::KeyframeRequest {
        sequence: 3,
        reason: KeyframeReason::DigestMismatch,
    };
    let (r, events) = run(digests.clone(), asks, request.clone());
    r.unwrap();
    assert_eq!(
        events.last(),
        Some(&ServerEvent::DigestRequested { every: 10 })
    );
    run(digests.clone(), asks, mismatch.clone()).0.unwrap();
    for (o, h) in [(offer(), asks), (digests, hello())] {
        for m in [request.clone(), mismatch.clone()] {
            let e = run(o.clone(), h, m).0.unwrap_err();
            assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
        }
    }
}
