//! Control messages and frame records against spec/session.md: the
//! examples of its section 8, round trips, and the bounds of the readers.

use glam::{Affine3A, Vec3};
use proptest::prelude::*;
use psao_proto::control::*;
use psao_proto::records::{RecordReader, record_prefix};
use psao_proto::{Close, CloseCode, SessionError};

/// The hex blocks of spec/session.md, by message name.
fn spec_examples() -> Vec<(String, Vec<u8>)> {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../spec/session.md"))
        .expect("spec/session.md");
    let mut out = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let Some(name) = line.strip_prefix("```hex ") else {
            continue;
        };
        let mut bytes = Vec::new();
        for l in lines.by_ref() {
            if l.starts_with("```") {
                break;
            }
            for b in l.split_whitespace() {
                bytes.push(u8::from_str_radix(b, 16).expect("hex"));
            }
        }
        out.push((name.trim().to_string(), bytes));
    }
    out
}

fn described(name: &str) -> Control {
    match name {
        "HELLO" => Control::Hello(Hello {
            version: 1,
            compressions: 0b111,
            point_formats: 1,
            max_frame_bytes: 1 << 20,
            max_payload_bytes: 1 << 20,
            max_mirror_bytes: 1 << 30,
            viewer: true,
            overflow: false,
            digest: false,
        }),
        "WELCOME" => Control::Welcome(Welcome {
            version: 1,
            compression: 2,
            point_format: 0,
            max_frame_bytes: 1 << 20,
            max_payload_bytes: 1 << 20,
            frame_rate: 60,
            culling: false,
            overflow: false,
            digest: false,
            scene: "default".into(),
        }),
        "HELLO-BIND" => match described("HELLO") {
            Control::Hello(h) => Control::Hello(Hello {
                point_formats: 0b11,
                ..h
            }),
            _ => unreachable!(),
        },
        "WELCOME-BIND" => match described("WELCOME") {
            Control::Welcome(w) => Control::Welcome(Welcome {
                point_format: 1,
                ..w
            }),
            _ => unreachable!(),
        },
        "HELLO-OVERFLOW" => match described("HELLO-BIND") {
            Control::Hello(h) => Control::Hello(Hello {
                overflow: true,
                ..h
            }),
            _ => unreachable!(),
        },
        "WELCOME-OVERFLOW" => match described("WELCOME-BIND") {
            Control::Welcome(w) => Control::Welcome(Welcome {
                overflow: true,
                ..w
            }),
            _ => unreachable!(),
        },
        "CAMERA" => Control::Camera(CameraPose {
            time_ms: 1000,
            eye: Vec3::new(0.0, 1.5, 5.0),
            target: Vec3::Y,
            fov_y: 1.0,
            aspect: 2.0,
        }),
        "ACK" => Control::Ack(7),
        "KEYFRAME_REQUEST" => Control::KeyframeRequest {
            sequence: 0,
            reason: KeyframeReason::NoState,
        },
        "MOVE_INSTANCE" => Control::MoveInstance {
            instance: 14,
            transform: Affine3A::from_translation(Vec3::new(1.0, 0.0, 2.0)),
        },
        "NOTICE" => Control::Notice {
            code: NoticeCode::FellBehind,
            text: "behind".into(),
        },
        "NOTICE-BELOW-RATE" => Control::Notice {
            code: NoticeCode::BelowRate,
            text: "41.5 of 60 Hz".into(),
        },
        "HELLO-DIGEST" => match described("HELLO-OVERFLOW") {
            Control::Hello(h) => Control::Hello(Hello { digest: true, ..h }),
            _ => unreachable!(),
        },
        "WELCOME-DIGEST" => match described("WELCOME-OVERFLOW") {
            Control::Welcome(w) => Control::Welcome(Welcome { digest: true, ..w }),
            _ => unreachable!(),
        },
        "DIGEST" => Control::Digest {
            sequence: 5,
            digest: 0x6BF7_0829,
        },
        "DIGEST_REQUEST" => Control::DigestRequest { every: 30 },
        "KEYFRAME_REQUEST-DIGEST" => Control::KeyframeRequest {
            sequence: 5,
            reason: KeyframeReason::DigestMismatch,
        },
        other => panic!("no description for example {other}"),
    }
}

#[test]
fn the_spec_examples_match_the_code() {
    let examples = spec_examples();
    let names: Vec<&str> = examples.iter().map(|e| e.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "HELLO",
            "WELCOME",
            "HELLO-BIND",
            "WELCOME-BIND",
            "HELLO-OVERFLOW",
            "WELCOME-OVERFLOW",
            "CAMERA",
            "ACK",
            "KEYFRAME_REQUEST",
            "MOVE_INSTANCE",
            "NOTICE",
            "NOTICE-BELOW-RATE",
            "HELLO-DIGEST",
            "WELCOME-DIGEST",
            "DIGEST",
            "DIGEST_REQUEST",
            "KEYFRAME_REQUEST-DIGEST"
        ],
        "every message type has an example"
    );
    for (name, bytes) in examples {
        let msg = described(&name);
        assert_eq!(
            &msg.to_bytes()[..],
            &bytes[..],
            "{name} encodes as in the spec"
        );
        let mut input = &bytes[..];
        let got = ControlReader::new().read(&mut input).unwrap();
        assert_eq!(got, Some(msg), "{name} decodes as in the spec");
        assert!(input.is_empty());
    }
    assert_eq!(record_prefix(&[0u8; 40]), [0x28, 0, 0, 0]);
}

fn code_of(bytes: &[u8]) -> CloseCode {
    error_of(bytes).close_code()
}

fn error_of(bytes: &[u8]) -> SessionError {
    let mut input = bytes;
    let mut r = ControlReader::new();
    loop {
        match r.read(&mut input) {
            Err(e) => return e,
            Ok(Some(_)) => {}
            Ok(None) if input.is_empty() => panic!("no error for {bytes:02x?}"),
            Ok(None) => {}
        }
    }
}

#[test]
fn session_errors_say_what_was_wrong_and_where() {
    assert_eq!(
        error_of(&[0x01, 0x04, 0x11]),
        SessionError::MessageTooLarge { length: 1025 }
    );
    assert_eq!(
        error_of(&[1, 0, 0x7f]),
        SessionError::UnknownMessage { kind: 0x7f }
    );
    let e = error_of(&[4, 0, 0x11, 1, 2, 3]);
    assert!(
        matches!(e, SessionError::Malformed { message: "ACK", .. }),
        "{e:?}"
    );
    assert_eq!(e.to_string(), "malformed ACK: body is 3 bytes, not 4");
    let mut hello = described("HELLO").to_bytes().to_vec();
    hello[7] = 2;
    assert_eq!(
        error_of(&hello),
        SessionError::VersionMismatch {
            message: "HELLO",
            version: 2,
            supported: 1
        }
    );
    // The close on the wire carries the code and the error's text.
    let close = Close::from(error_of(&[0, 0]));
    assert_eq!(close.code, CloseCode::MessageTooLarge);
    assert_eq!(close.reason, "control message length 0 (allowed 1..=1024)");
}

#[test]
fn malformed_messages_close_with_the_specified_code() {
    use CloseCode::*;
    assert_eq!(code_of(&[0, 0]), MessageTooLarge, "length 0");
    assert_eq!(code_of(&[0x01, 0x04, 0x11]), MessageTooLarge, "length 1025");
    assert_eq!(code_of(&[0xff, 0xff]), MessageTooLarge);
    assert_eq!(code_of(&[1, 0, 0x7f]), ProtocolViolation, "unknown type");
    assert_eq!(
        code_of(&[4, 0, 0x11, 1, 2, 3]),
        ProtocolViolation,
        "short ACK"
    );
    assert_eq!(
        code_of(&[6, 0, 0x11, 1, 2, 3, 4, 5]),
        ProtocolViolation,
        "long ACK"
    );
    assert_eq!(
        code_of(&[6, 0, 0x12, 0, 0, 0, 0, 5]),
        ProtocolViolation,
        "reason 5 (4, a digest mismatch, is checked against the session)"
    );
    let mut hello = described("HELLO").to_bytes().to_vec();
    hello[3] = b'X';
    assert_eq!(code_of(&hello), ProtocolViolation, "magic");
    let mut hello = described("HELLO").to_bytes().to_vec();
    hello[7] = 2;
    assert_eq!(code_of(&hello), VersionMismatch);
    let mut hello = described("HELLO").to_bytes().to_vec();
    hello[27] = 0x81;
    assert_eq!(code_of(&hello), ProtocolViolation, "reserved flag");
    let mut hello = described("HELLO").to_bytes().to_vec();
    hello[9] = 0x06;
    assert_eq!(
        code_of(&hello),
        ProtocolViolation,
        "compression 0 must be accepted"
    );
    let mut cam = described("CAMERA").to_bytes().to_vec();
    cam[7..11].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(code_of(&cam), ProtocolViolation, "NaN");
    let mut cam = described("CAMERA").to_bytes().to_vec();
    cam[31..35].copy_from_slice(&4.0f32.to_le_bytes());
    assert_eq!(code_of(&cam), ProtocolViolation, "field of view above pi");
    let mut welcome = described("WELCOME").to_bytes().to_vec();
    welcome[18] = 9;
    assert_eq!(code_of(&welcome), ProtocolViolation, "name length");
    // A later version's WELCOME, of another size, is a version mismatch.
    assert_eq!(code_of(&[4, 0, 0x02, 2, 0, 9]), VersionMismatch);
    assert_eq!(
        code_of(&[4, 0, 0x01, b'P', b'S', b'A']),
        ProtocolViolation,
        "short HELLO"
    );
    assert_eq!(
        code_of(&[5, 0, 0x20, 1, 2, 0xff, 0xfe]),
        ProtocolViolation,
        "NOTICE text not UTF-8"
    );
    // A failed reader stays failed.
    let mut r = ControlReader::new();
    assert!(r.read(&mut &[0u8, 0][..]).is_err());
    assert!(r.read(&mut &described("ACK").to_bytes()[..]).is_err());
}

#[test]
fn readers_hold_at_most_one_message() {
    // Byte by byte, a stream of messages comes out whole and in order, and
    // the reader never holds more than one message.
    let msgs: Vec<Control> = ["HELLO", "ACK", "NOTICE", "MOVE_INSTANCE", "WELCOME"]
        .iter()
        .map(|n| described(n))
        .collect();
    let stream: Vec<u8> = msgs.iter().flat_map(|m| m.to_bytes().to_vec()).collect();
    let mut r = ControlReader::new();
    let mut got = Vec::new();
    for b in &stream {
        let mut input = std::slice::from_ref(b);
        if let Some(m) = r.read(&mut input).unwrap() {
            got.push(m);
        }
        assert!(r.buffered() <= 1026);
    }
    assert_eq!(got, msgs);
    // A 1,024-byte message is the largest.
    let mut big = vec![0x00, 0x04, 0x20, 3, 200];
    big.extend(std::iter::repeat_n(b'a', 200));
    big.resize(1026, 0);
    assert_eq!(
        code_of(&big[..]),
        CloseCode::ProtocolViolation,
        "text length does not add up"
    );
    // Frame records: split anywhere, bounded by the negotiated size.
    let frames: Vec<Vec<u8>> = (0..5).map(|k| vec![k as u8; 32 + 17 * k]).collect();
    let mut stream = Vec::new();
    for f in &frames {
        stream.extend_from_slice(&record_prefix(f));
        stream.extend_from_slice(f);
    }
    for chunk in [1, 3, 7, 1000] {
        let mut r = RecordReader::new(1000);
        let mut out = Vec::new();
        for piece in stream.chunks(chunk) {
            let mut input = piece;
            while !input.is_empty() {
                if let Some(f) = r.read(&mut input).unwrap() {
                    out.push(f.to_vec());
                }
            }
        }
        assert_eq!(out, frames, "chunks of {chunk}");
    }
    let mut r = RecordReader::new(1000);
    let e = r.read(&mut &1001u32.to_le_bytes()[..]).unwrap_err();
    assert_eq!(e.close_code(), CloseCode::ProtocolViolation);
    assert_eq!(
        e,
        SessionError::FrameRecordSize {
            length: 1001,
            min: 32,
            max: 1000
        }
    );
    let mut r = RecordReader::new(1000);
    assert!(
        r.read(&mut &31u32.to_le_bytes()[..]).is_err(),
        "shorter than a header"
    );
}

proptest! {
    #[test]
    fn control_messages_round_trip(
        seq in any::<u32>(),
        inst in any::<u32>(),
        f in prop::array::uniform12(-1e6f32..1e6),
        text in "[a-z ]{0,250}",
        code in 1u8..=3,
        flags in any::<bool>(),
    ) {
        let msgs = [
            Control::Ack(seq),
            Control::KeyframeRequest { sequence: seq, reason: KeyframeReason::DecodeError },
            Control::KeyframeRequest { sequence: seq, reason: KeyframeReason::DigestMismatch },
            Control::Digest { sequence: seq, digest: inst },
            Control::DigestRequest { every: seq as u16 },
            Control::MoveInstance { instance: inst, transform: Affine3A::from_cols_array(&f) },
            Control::Notice {
                code: match code { 1 => NoticeCode::EventRefused, 2 => NoticeCode::FellBehind, 4 => NoticeCode::BelowRate, c => NoticeCode::Other(c) },
                text: text.clone(),
            },
            Control::Welcome(Welcome {
                version: 1, compression: 1, point_format: 0, max_frame_bytes: seq,
                max_payload_bytes: inst, frame_rate: 30, culling: flags, overflow: !flags, digest: flags, scene: text.clone(),
            }),
        ];
        for m in msgs {
            let bytes = m.to_bytes();
            let mut input = &bytes[..];
            let back = ControlReader::new().read(&mut input).unwrap().unwrap();
            // Texts are cut to 200 bytes.
            let want = match m {
                Control::Notice { code, text } => Control::Notice { code, text: clip_text(&text).to_string() },
                Control::Welcome(w) => Control::Welcome(Welcome { scene: clip_text(&w.scene).to_string(), ..w }),
                m => m,
            };
            prop_assert_eq!(back, want);
        }
    }

    #[test]
    fn any_bytes_never_panic_the_readers(bytes in prop::collection::vec(any::<u8>(), 0..2000)) {
        let mut input = &bytes[..];
        let mut r = ControlReader::new();
        while !input.is_empty() {
            match r.read(&mut input) {
                Ok(_) => prop_assert!(r.buffered() <= 1026),
                Err(_) => break,
            }
        }
        let mut input = &bytes[..];
        let mut r = RecordReader::new(1 << 16);
        while !input.is_empty() {
            if r.read(&mut input).is_err() {
                break;
            }
        }
    }
}
