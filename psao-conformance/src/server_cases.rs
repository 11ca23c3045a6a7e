//! The cases that drive a server under test (spec/session.md), each on a
//! fresh connection. [`run`] runs them all, or those whose id starts with
//! a filter.

use std::future::Future;
use std::pin::Pin;
use std::time::{Duration, Instant};

use psao_proto::CloseCode;
use psao_proto::control::{CameraPose, Control, Hello, KeyframeReason};

use crate::probe::{Ended, Probe, Target, example_hello, open_hello};
use crate::report::{CaseResult, Outcome, Report};

type CaseFuture<'a> = Pin<Box<dyn Future<Output = Outcome> + Send + 'a>>;

/// One case: an id, the section it checks, what it checks, and the
/// probe that runs it.
pub struct Case {
    /// Stable id.
    pub id: &'static str,
    /// Spec section.
    pub section: &'static str,
    /// What is checked.
    pub title: &'static str,
    run: for<'a> fn(&'a Target) -> CaseFuture<'a>,
}

/// Turns a `Result` of a probe into an outcome; a refusal of the
/// example's options skips (see `hello.example`).
fn outcome(r: Result<(), String>) -> Outcome {
    match Outcome::of(r) {
        Outcome::Skipped(why) => {
            Outcome::Skipped(format!("the server refused the example's options: {why}"))
        }
        o => o,
    }
}

/// A probe that has completed the handshake with `hello` and read the
/// first keyframe.
async fn joined(t: &Target, hello: Hello) -> Result<Probe, String> {
    let mut p = Probe::connect(t).await?;
    p.hello(hello).await?;
    if !p.await_keyframe(0, Duration::from_secs(10)).await? {
        return Err("no keyframe within 10 s of WELCOME".into());
    }
    if !p.seen.first().is_some_and(|f| f.1) {
        return Err(format!("the first frame was a delta: {:?}", p.seen.first()));
    }
    Ok(p)
}

/// Sends `bytes` on the control stream of a fresh connection (after
/// `hello`, if given) and expects the close `code`.
async fn violation(t: &Target, hello: Option<Hello>, bytes: Vec<u8>, code: CloseCode) -> Outcome {
    outcome(
        async {
            let mut p = Probe::connect(t).await?;
            if let Some(h) = hello {
                p.hello(h).await?;
            }
            p.write(&bytes).await?;
            p.expect_close(code, Duration::from_secs(8)).await
        }
        .await,
    )
}

fn bytes(m: Control) -> Vec<u8> {
    m.to_bytes().to_vec()
}

/// A control message with any type and body.
fn raw_message(kind: u8, body: &[u8]) -> Vec<u8> {
    let mut m = ((body.len() + 1) as u16).to_le_bytes().to_vec();
    m.push(kind);
    m.extend_from_slice(body);
    m
}

macro_rules! case {
    ($id:literal, $section:literal, $title:literal, |$t:ident| $body:expr) => {
        Case {
            id: $id,
            section: $section,
            title: $title,
            run: |$t| Box::pin(async move { $body }),
        }
    };
}

/// Every case, in the order they run.
pub fn cases() -> Vec<Case> {
    vec![
        case!(
            "hello.example",
            "session.md 3.1, 3.2, 8",
            "the spec's example HELLO gets a WELCOME within its limits, then a keyframe first",
            |t| {
                outcome(
                    async {
                        let mut p = Probe::connect(t).await?;
                        let w = match p.hello(example_hello()).await {
                            Ok(w) => w,
                            Err(e) => match p.ended(Duration::from_millis(100)).await {
                                // Options the server's frames need that the
                                // example lacks (spec/session.md 3.2): allowed.
                                Ended::Closed(CloseCode::CapabilityMismatch, reason)
                                    if !reason.contains("bytes") =>
                                {
                                    return Err(format!("SKIP:{reason}"));
                                }
                                _ => return Err(e),
                            },
                        };
                        if w.version != 1 || w.compression > 2 {
                            return Err(format!(
                                "WELCOME says version {} compression {}",
                                w.version, w.compression
                            ));
                        }
                        if w.max_frame_bytes > 1 << 20 || w.max_payload_bytes > 1 << 20 {
                            return Err(format!(
                                "WELCOME's limits {} / {} are above the HELLO's 1 MiB",
                                w.max_frame_bytes, w.max_payload_bytes
                            ));
                        }
                        if !p.await_keyframe(0, Duration::from_secs(10)).await? {
                            return Err("no keyframe within 10 s".into());
                        }
                        match p.seen.first() {
                            Some((_, true)) => Ok(()),
                            other => Err(format!("the first frame is not a keyframe: {other:?}")),
                        }
                    }
                    .await,
                )
            }
        ),
        case!(
            "hello.example-limits",
            "session.md 3.1, 3.2",
            "a HELLO with the example's 1 MiB limits and every option gets a WELCOME within them",
            |t| {
                outcome(
                    async {
                        let mut p = Probe::connect(t).await?;
                        let h = Hello {
                            max_frame_bytes: 1 << 20,
                            max_payload_bytes: 1 << 20,
                            ..open_hello()
                        };
                        let w = p.hello(h).await?;
                        if w.max_frame_bytes > 1 << 20 || w.max_payload_bytes > 1 << 20 {
                            return Err(format!(
                                "WELCOME's limits {} / {} exceed the HELLO's",
                                w.max_frame_bytes, w.max_payload_bytes
                            ));
                        }
                        if !p.await_keyframe(0, Duration::from_secs(10)).await? {
                            return Err("no keyframe within 10 s".into());
                        }
                        Ok(())
                    }
                    .await,
                )
            }
        ),
        case!(
            "hello.minimum-limits",
            "session.md 3.1, 3.2",
            "HELLO with the minimum limits (65,536) is served within them, or refused naming a larger size",
            |t| {
                outcome(
                    async {
                        let mut p = Probe::connect(t).await?;
                        let h = Hello {
                            max_frame_bytes: 65_536,
                            max_payload_bytes: 65_536,
                            ..open_hello()
                        };
                        p.send(Control::Hello(h)).await?;
                        match p.next_control(Duration::from_secs(10)).await {
                            Ok(Some(Control::Welcome(w))) => {
                                if w.max_frame_bytes > 65_536 || w.max_payload_bytes > 65_536 {
                                    return Err(format!(
                                        "WELCOME's limits {} / {} exceed the HELLO's",
                                        w.max_frame_bytes, w.max_payload_bytes
                                    ));
                                }
                                p.read_frames(Duration::from_secs(1)).await?;
                                if p.seen.is_empty() {
                                    return Err("no frame within 1 s".into());
                                }
                                Ok(())
                            }
                            Ok(other) => Err(format!("expected WELCOME or a close, got {other:?}")),
                            Err(_) => match p.ended(Duration::from_secs(2)).await {
                                Ended::Closed(CloseCode::CapabilityMismatch, reason)
                                    if reason
                                        .split(|c: char| !c.is_ascii_digit())
                                        .filter_map(|n| n.parse::<u64>().ok())
                                        .any(|n| n > 65_536) =>
                                {
                                    Ok(())
                                }
                                other => Err(format!(
                                    "refused without naming a size above 65,536: {other}"
                                )),
                            },
                        }
                    }
                    .await,
                )
            }
        ),
        case!(
            "hello.bad-magic",
            "session.md 3.1",
            "a HELLO whose magic is not PSAO is protocol_violation",
            |t| {
                let mut b = bytes(Control::Hello(example_hello()));
                b[3] = b'X';
                violation(t, None, b, CloseCode::ProtocolViolation).await
            }
        ),
        case!(
            "hello.version",
            "session.md 3.1, 7",
            "a HELLO of version 2 is version_mismatch",
            |t| {
                let mut b = bytes(Control::Hello(example_hello()));
                b[7] = 2;
                violation(t, None, b, CloseCode::VersionMismatch).await
            }
        ),
        case!(
            "hello.reserved-bit",
            "session.md 3.1",
            "a HELLO with a reserved flags bit is protocol_violation",
            |t| {
                let mut b = bytes(Control::Hello(example_hello()));
                let last = b.len() - 1;
                b[last] |= 0x80;
                violation(t, None, b, CloseCode::ProtocolViolation).await
            }
        ),
        case!(
            "hello.limits-below-minimum",
            "session.md 3.1",
            "a HELLO offering 65,535-byte frames is protocol_violation",
            |t| {
                let h = Hello {
                    max_frame_bytes: 65_535,
                    ..example_hello()
                };
                violation(
                    t,
                    None,
                    bytes(Control::Hello(h)),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "hello.wrong-size",
            "session.md 3",
            "a HELLO body of 24 bytes is protocol_violation",
            |t| {
                let b = bytes(Control::Hello(example_hello()));
                violation(
                    t,
                    None,
                    raw_message(0x01, &b[3..b.len() - 1]),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "open.first-not-hello",
            "session.md 5.1",
            "an ACK before HELLO is protocol_violation",
            |t| {
                violation(
                    t,
                    None,
                    bytes(Control::Ack(1)),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "open.second-hello",
            "session.md 5.1",
            "a second HELLO is protocol_violation",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    bytes(Control::Hello(open_hello())),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "open.welcome-from-client",
            "session.md 5.1",
            "a WELCOME sent by the client is protocol_violation (a message of the other role)",
            |t| {
                let w = psao_proto::control::Welcome {
                    version: 2,
                    compression: 0,
                    point_format: 0,
                    max_frame_bytes: 1 << 20,
                    max_payload_bytes: 1 << 20,
                    frame_rate: 60,
                    culling: false,
                    overflow: false,
                    digest: false,
                    scene: String::new(),
                };
                violation(
                    t,
                    None,
                    bytes(Control::Welcome(w)),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "open.handshake-timeout",
            "session.md 5.1, 6",
            "no HELLO within 5 s is handshake_timeout",
            |t| {
                outcome(
                    async {
                        let mut p = Probe::connect(t).await?;
                        // Open the stream with an incomplete message: no HELLO.
                        p.write(&[0x1a]).await?;
                        let start = Instant::now();
                        p.expect_close(CloseCode::HandshakeTimeout, Duration::from_secs(9))
                            .await?;
                        let s = start.elapsed().as_secs_f64();
                        if s < 3.5 {
                            return Err(format!("closed after {s:.1} s, well before 5 s"));
                        }
                        Ok(())
                    }
                    .await,
                )
            }
        ),
        case!(
            "uplink.length-zero",
            "session.md 3, 6",
            "a control message of length 0 is message_too_large",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    vec![0, 0],
                    CloseCode::MessageTooLarge,
                )
                .await
            }
        ),
        case!(
            "uplink.length-1025",
            "session.md 3, 6",
            "a control message of length 1025 is message_too_large",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    vec![0x01, 0x04, 0x11],
                    CloseCode::MessageTooLarge,
                )
                .await
            }
        ),
        case!(
            "uplink.unknown-type",
            "session.md 3",
            "an undefined message type is protocol_violation",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    raw_message(0x7f, &[0; 4]),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "uplink.wrong-body",
            "session.md 3",
            "an ACK with a 5-byte body is protocol_violation",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    raw_message(0x11, &[1, 2, 3, 4, 5]),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "uplink.rate",
            "session.md 6, 7",
            "300 messages in one write are rate_exceeded",
            |t| {
                let acks: Vec<u8> = (0..300u32).flat_map(|s| bytes(Control::Ack(s))).collect();
                violation(t, Some(open_hello()), acks, CloseCode::RateExceeded).await
            }
        ),
        case!(
            "uplink.camera-not-viewer",
            "session.md 3.3",
            "CAMERA from a client that did not set viewer is protocol_violation",
            |t| {
                let h = Hello {
                    viewer: false,
                    ..open_hello()
                };
                violation(
                    t,
                    Some(h),
                    bytes(Control::Camera(pose(1.0))),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "uplink.camera-out-of-range",
            "session.md 3.3",
            "CAMERA with fov_y of 4 radians is protocol_violation",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    bytes(Control::Camera(pose(4.0))),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "uplink.non-finite",
            "session.md 3",
            "MOVE_INSTANCE holding NaN is protocol_violation",
            |t| {
                let mut body = 0u32.to_le_bytes().to_vec();
                for k in 0..12 {
                    body.extend(if k == 5 { f32::NAN } else { 1.0f32 }.to_le_bytes());
                }
                violation(
                    t,
                    Some(open_hello()),
                    raw_message(0x13, &body),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "keyframe.reason-gap",
            "session.md 3.5",
            "KEYFRAME_REQUEST reason 0 is answered with a keyframe",
            |t| keyframe_case(t, KeyframeReason::Gap).await
        ),
        case!(
            "keyframe.reason-decode",
            "session.md 3.5",
            "KEYFRAME_REQUEST reason 1 is answered with a keyframe",
            |t| keyframe_case(t, KeyframeReason::DecodeError).await
        ),
        case!(
            "keyframe.reason-other",
            "session.md 3.5",
            "KEYFRAME_REQUEST reason 2 is answered with a keyframe",
            |t| keyframe_case(t, KeyframeReason::Other).await
        ),
        case!(
            "keyframe.reason-no-state",
            "session.md 3.5",
            "KEYFRAME_REQUEST reason 3 is answered with a keyframe",
            |t| keyframe_case(t, KeyframeReason::NoState).await
        ),
        case!(
            "keyframe.reason-unknown",
            "session.md 3.5",
            "KEYFRAME_REQUEST reason 5 is protocol_violation",
            |t| {
                violation(
                    t,
                    Some(open_hello()),
                    raw_message(0x12, &[0, 0, 0, 0, 5]),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "keyframe.reason-digest-without-digests",
            "session.md 3.5",
            "reason 4 in a session without digests is protocol_violation",
            |t| {
                let m = Control::KeyframeRequest {
                    sequence: 0,
                    reason: KeyframeReason::DigestMismatch,
                };
                violation(
                    t,
                    Some(open_hello()),
                    bytes(m),
                    CloseCode::ProtocolViolation,
                )
                .await
            }
        ),
        case!(
            "move.answered",
            "session.md 3.6",
            "MOVE_INSTANCE is answered: a newer transform for the instance, or NOTICE 1",
            |t| {
                outcome(
                    async {
                        let mut p = joined(t, open_hello()).await?;
                        let Some((id, before)) = p
                            .decoder
                            .mirror()
                            .instances()
                            .next()
                            .map(|(id, m)| (id, m.transform().map(|t| t.sequence)))
                        else {
                            return Err("the keyframe holds no instance to move".into());
                        };
                        p.send(Control::MoveInstance {
                            instance: id,
                            transform: glam::Affine3A::IDENTITY,
                        })
                        .await?;
                        let deadline = Instant::now() + Duration::from_secs(3);
                        while Instant::now() < deadline {
                            p.read_frames(Duration::from_millis(100)).await?;
                            let now = p
                                .decoder
                                .mirror()
                                .instance(id)
                                .and_then(|m| m.transform())
                                .map(|t| t.sequence);
                            if now.is_some() && now != before {
                                return Ok(());
                            }
                            if let Ok(Some(Control::Notice {
                                code: psao_proto::control::NoticeCode::EventRefused,
                                ..
                            })) = p.next_control(Duration::from_millis(1)).await
                            {
                                return Ok(());
                            }
                        }
                        Err(format!(
                            "no new transform for instance {id} and no NOTICE 1 within 3 s"
                        ))
                    }
                    .await,
                )
            }
        ),
        case!(
            "camera.accepted",
            "session.md 3.3",
            "a viewer's CAMERA is taken: frames go on, no close",
            |t| {
                outcome(
                    async {
                        let mut p = joined(t, open_hello()).await?;
                        p.send(Control::Camera(pose(1.0))).await?;
                        p.read_frames(Duration::from_secs(1)).await?;
                        match p.ended(Duration::from_millis(10)).await {
                            Ended::Other(_) => {}
                            closed => return Err(format!("the connection ended: {closed}")),
                        }
                        Ok(())
                    }
                    .await,
                )
            }
        ),
        case!(
            "digest.on-request",
            "session.md 3.8, 3.9",
            "with digests negotiated, DIGEST_REQUEST is answered with a DIGEST equal to the mirror's",
            |t| {
                let hello = Hello {
                    digest: true,
                    ..open_hello()
                };
                let mut p = match Probe::connect(t).await {
                    Ok(p) => p,
                    Err(e) => return Outcome::Failed(e),
                };
                let w = match p.hello(hello).await {
                    Ok(w) => w,
                    Err(e) => return Outcome::Failed(e),
                };
                if !w.digest {
                    return Outcome::Skipped(
                        "the server does not offer digests (WELCOME.flags.digest is 0)".into(),
                    );
                }
                outcome(digest_case(&mut p).await)
            }
        ),
        case!(
            "close.control-finished",
            "session.md 2.1",
            "a client that finishes its control stream is closed with protocol_violation",
            |t| {
                outcome(
                    async {
                        let mut p = Probe::connect(t).await?;
                        p.hello(open_hello()).await?;
                        p.send.finish().map_err(|e| format!("cannot finish: {e}"))?;
                        p.expect_close(CloseCode::ProtocolViolation, Duration::from_secs(5))
                            .await
                    }
                    .await,
                )
            }
        ),
    ]
}

fn pose(fov_y: f32) -> CameraPose {
    CameraPose {
        time_ms: 0,
        eye: glam::Vec3::new(0.0, 2.0, 6.0),
        target: glam::Vec3::ZERO,
        fov_y,
        aspect: 1.5,
    }
}

async fn keyframe_case(t: &Target, reason: KeyframeReason) -> Outcome {
    outcome(
        async {
            let mut p = joined(t, open_hello()).await?;
            let sequence = if reason == KeyframeReason::NoState {
                0
            } else {
                p.decoder.mirror().sequence().unwrap_or(0)
            };
            let after = p.seen.len();
            p.send(Control::KeyframeRequest { sequence, reason })
                .await?;
            if p.await_keyframe(after, Duration::from_secs(3)).await? {
                Ok(())
            } else {
                Err("no keyframe within 3 s of the request".into())
            }
        }
        .await,
    )
}

async fn digest_case(p: &mut Probe) -> Result<(), String> {
    p.digests = Some(Default::default());
    if !p.await_keyframe(0, Duration::from_secs(10)).await? {
        return Err("no keyframe within 10 s".into());
    }
    p.send(Control::DigestRequest { every: 0 }).await?;
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut pending = None;
    while Instant::now() < deadline {
        if let Some(Control::Digest { sequence, digest }) =
            p.next_control(Duration::from_millis(50)).await?
        {
            pending = Some((sequence, digest));
        }
        if let Some((s, d)) = pending {
            let mine = p
                .digests
                .as_ref()
                .and_then(|ds| ds.iter().rev().find(|x| x.0 == s))
                .map(|x| x.1);
            match mine {
                Some(Some(m)) if m == d => return Ok(()),
                Some(m) => return Err(format!("DIGEST {d:08x} for {s}, the mirror's is {m:08x?}")),
                None => {}
            }
        }
        p.read_frames(Duration::from_millis(50)).await?;
    }
    Err(match pending {
        Some((s, _)) => format!("a DIGEST for {s} came, but the frames never reached it"),
        None => "no DIGEST within 5 s of DIGEST_REQUEST".into(),
    })
}

/// What a probe reports for a connection that ended with no application
/// close at all (see [`CaseResult::attempts`]).
const INCONCLUSIVE: &str = "without an application close";

/// Runs the cases whose id starts with `filter` (all for ""), one after
/// the other, each on its own connection and bounded in time.
pub async fn run(target: &Target, filter: &str) -> Report {
    let mut report = Report {
        target: target.addr.to_string(),
        cases: Vec::new(),
    };
    for case in cases().into_iter().filter(|c| c.id.starts_with(filter)) {
        let mut attempts = 0;
        let result = loop {
            attempts += 1;
            let start = Instant::now();
            let outcome =
                match tokio::time::timeout(Duration::from_secs(30), (case.run)(target)).await {
                    Ok(o) => o,
                    Err(_) => Outcome::Failed("the case did not end within 30 s".into()),
                };
            let inconclusive =
                matches!(&outcome, Outcome::Failed(why) if why.contains(INCONCLUSIVE));
            if !inconclusive || attempts == 3 {
                break CaseResult {
                    attempts,
                    ..CaseResult::new(case.id, case.section, case.title, outcome, start.elapsed())
                };
            }
        };
        report.cases.push(result);
    }
    report
}
