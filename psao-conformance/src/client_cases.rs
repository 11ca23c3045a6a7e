//! The cases that drive a client under test (spec/session.md): a scripted
//! server session on one connection. The harness accepts the client,
//! checks its `HELLO`, answers with `WELCOME` at the client's exact
//! limits, and streams a small grid through a late join, a gap, a
//! corrupt frame, a resynchronization with `NOTICE` code 2, every
//! `NOTICE` code, a frame of exactly its `max_frame_bytes`, and (when the
//! client checks digests) a wrong `DIGEST`,
//! checking what the client sends back each time.

use std::time::{Duration, Instant};

use glam::Vec3;
use psao_codec::{EncodedFrame, Encoder, EncoderConfig, GridTable, InstanceDef};
use psao_proto::control::{Control, Hello, KeyframeReason, NoticeCode, Sender, Welcome};

use crate::probe::ControlIn;
use crate::report::{CaseResult, Outcome, Report};

/// What the client sent, as the harness reads it.
struct Uplink(ControlIn);

impl Uplink {
    /// The next message within `wait` (`Ok(None)`: none came).
    async fn next(&mut self, wait: Duration) -> Result<Option<Control>, String> {
        self.0.next(wait).await
    }

    /// Waits up to `wait` for a message `want` accepts, ignoring others
    /// (`ACK`s, `CAMERA`s); the message, or what happened instead.
    async fn expect(
        &mut self,
        wait: Duration,
        what: &str,
        want: impl Fn(&Control) -> bool,
    ) -> Result<Control, String> {
        let deadline = Instant::now() + wait;
        let mut others = Vec::new();
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match self.next(left).await? {
                Some(m) if want(&m) => return Ok(m),
                Some(m) => others.push(m.kind()),
                None => break,
            }
        }
        Err(format!(
            "no {what} within {} ms (got message types {others:02x?})",
            wait.as_millis()
        ))
    }
}

/// The scripted server side: a small grid and its encoder.
struct Script {
    table: GridTable,
    enc: Encoder,
    frames: quinn::SendStream,
    control: quinn::SendStream,
    k: u32,
}

impl Script {
    fn new(frames: quinn::SendStream, control: quinn::SendStream) -> Script {
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
        // A late join: the stream is already at sequence 1000.
        let enc = Encoder::starting_at(
            EncoderConfig {
                compression: psao_codec::Compression::None,
                checksum: true,
                ..EncoderConfig::default()
            },
            1000,
        );
        Script {
            table: GridTable::new(0, def, 1024).expect("a valid grid"),
            enc,
            frames,
            control,
            k: 0,
        }
    }

    fn keyframe(&mut self) -> Result<EncodedFrame, String> {
        let mut kf = self.enc.keyframe();
        kf.snapshot(&self.table).map_err(|e| e.to_string())?;
        kf.finish()
            .map_err(|e| e.to_string())?
            .ok_or("an empty keyframe".into())
    }

    fn delta(&mut self) -> Result<EncodedFrame, String> {
        let k = self.k;
        self.k += 1;
        let x = 0.25 + (k % 14) as f32 * 0.25;
        self.table
            .set_point(
                k % 512,
                Vec3::new(x, 0.3, 1.0 + (k / 14 % 8) as f32 * 0.25),
                Vec3::Y,
                (k % 10) as f32 / 10.0,
            )
            .map_err(|e| e.to_string())?;
        let mut d = self.enc.delta();
        d.changes(&mut self.table);
        d.finish()
            .map_err(|e| e.to_string())?
            .ok_or("an empty delta".into())
    }

    async fn send(&mut self, frame: &[u8]) -> Result<(), String> {
        self.frames
            .write_all(&(frame.len() as u32).to_le_bytes())
            .await
            .map_err(|e| format!("cannot write a frame: {e}"))?;
        self.frames
            .write_all(frame)
            .await
            .map_err(|e| format!("cannot write a frame: {e}"))
    }

    async fn control(&mut self, m: Control) -> Result<(), String> {
        self.control
            .write_all(&m.to_bytes())
            .await
            .map_err(|e| format!("cannot write on the control stream: {e}"))
    }
}

/// `frame` (uncompressed, with or without checksum) as a zstd frame of
/// exactly `size` bytes: its payload compressed, then a skippable frame
/// (RFC 8878 3.1.2) filling the rest, the header's lengths and CRC fixed.
fn exact_frame(frame: &[u8], size: u32) -> Result<Vec<u8>, String> {
    let payload = &frame[32..];
    let z = zstd::bulk::compress(payload, 3).map_err(|e| e.to_string())?;
    let pad = (size as usize)
        .checked_sub(32 + z.len() + 8)
        .ok_or("the limit is smaller than the frame")?;
    let mut wire = z;
    wire.extend(0x184D_2A50u32.to_le_bytes());
    wire.extend((pad as u32).to_le_bytes());
    wire.resize(wire.len() + pad, 0);
    let mut f = frame[..32].to_vec();
    f[5] |= 2; // CHECKSUM
    f[6] = 2; // zstd
    f[24..28].copy_from_slice(&(wire.len() as u32).to_le_bytes());
    let mut h = crc32fast::Hasher::new();
    h.update(&f[..28]);
    h.update(&wire);
    let crc = h.finalize();
    f[28..32].copy_from_slice(&crc.to_le_bytes());
    f.extend_from_slice(&wire);
    debug_assert_eq!(f.len(), size as usize);
    Ok(f)
}

/// One case of the scripted session: id, spec section, what it checks.
struct Meta(&'static str, &'static str, &'static str);

const HELLO: Meta = Meta(
    "client.hello",
    "session.md 3.1, 5.1",
    "the client's first message is a valid HELLO",
);
const JOIN: Meta = Meta(
    "client.join",
    "session.md 3.4, 5.1",
    "a late join: the client applies a keyframe at a later sequence and acknowledges it",
);
const GAP: Meta = Meta(
    "client.gap",
    "session.md 3.5",
    "a gap in the deltas makes the client ask for a keyframe with reason 0, and the keyframe resyncs it",
);
const CORRUPT: Meta = Meta(
    "client.corrupt",
    "session.md 3.5, wire-format.md 3.1",
    "a corrupt frame makes the client ask for a keyframe with reason 1",
);
const RESYNC: Meta = Meta(
    "client.resync",
    "session.md 5.2",
    "after NOTICE 2 the client takes a keyframe 20 sequences ahead and goes on",
);
const NOTICES: Meta = Meta(
    "client.notices",
    "session.md 3.7",
    "NOTICE codes 1, 3, 4 and an unknown 200 are not errors",
);
const LIMIT: Meta = Meta(
    "client.limit-exact",
    "session.md 3.1, 3.2, wire-format.md 3.2",
    "a frame of exactly the HELLO's max_frame_bytes (zstd with a skippable frame) applies",
);
const DIGEST: Meta = Meta(
    "client.digest-mismatch",
    "session.md 3.8",
    "a DIGEST that differs from the client's mirror makes it ask for a keyframe with reason 4",
);
const SHUTDOWN: Meta = Meta(
    "client.shutdown",
    "session.md 5.3",
    "the client is still connected when the server finishes the frame stream and shuts down",
);

/// The report being written, timing each case from the end of the last.
struct Run {
    report: Report,
    last: Instant,
}

impl Run {
    fn record(&mut self, m: &Meta, r: Result<(), String>) {
        let took = self.last.elapsed();
        self.report
            .cases
            .push(CaseResult::new(m.0, m.1, m.2, Outcome::of(r), took));
        self.last = Instant::now();
    }
}

/// Sends a keyframe of the current state and waits for its `ACK`.
async fn keyframe_acked(s: &mut Script, up: &mut Uplink, what: &str) -> Result<(), String> {
    let kf = s.keyframe()?;
    s.send(&kf.bytes).await?;
    let seq = kf.sequence;
    up.expect(
        Duration::from_secs(3),
        what,
        |m| matches!(m, Control::Ack(a) if *a == seq),
    )
    .await
    .map(|_| ())
}

/// Waits for a keyframe request with `reason`, then answers it and waits
/// for the answer's `ACK`.
async fn answered(s: &mut Script, up: &mut Uplink, reason: KeyframeReason) -> Result<(), String> {
    up.expect(
        Duration::from_secs(3),
        &format!("KEYFRAME_REQUEST with reason {reason:?}"),
        |m| matches!(m, Control::KeyframeRequest { reason: r, .. } if *r == reason),
    )
    .await?;
    keyframe_acked(s, up, "ACK of the answering keyframe").await
}

/// Accepts the first client within `wait` and reads its `HELLO`.
async fn handshake(
    endpoint: &quinn::Endpoint,
    wait: Duration,
) -> Result<(quinn::Connection, quinn::SendStream, Uplink, Hello), String> {
    let incoming = tokio::time::timeout(wait, endpoint.accept())
        .await
        .map_err(|_| format!("no client connected within {} s", wait.as_secs()))?
        .ok_or("the endpoint closed")?;
    let conn = incoming
        .await
        .map_err(|e| format!("the QUIC handshake failed: {e}"))?;
    let (send, recv) = tokio::time::timeout(Duration::from_secs(5), conn.accept_bi())
        .await
        .map_err(|_| "no control stream within 5 s".to_string())?
        .map_err(|e| e.to_string())?;
    let mut up = Uplink(ControlIn::new(recv, Sender::Client, "the client"));
    match up.next(Duration::from_secs(5)).await {
        Ok(Some(Control::Hello(h))) => Ok((conn, send, up, h)),
        Ok(Some(other)) => {
            conn.close(1u32.into(), b"conformance: no HELLO");
            Err(format!(
                "the first message is type 0x{:02x}, not HELLO",
                other.kind()
            ))
        }
        Ok(None) => Err("no HELLO within 5 s".into()),
        Err(e) => Err(e),
    }
}

/// Runs the scripted session with the first client that connects to
/// `endpoint` within `wait`.
pub async fn run(endpoint: &quinn::Endpoint, wait: Duration) -> Report {
    let mut run = Run {
        report: Report {
            target: "the client under test".into(),
            cases: Vec::new(),
        },
        last: Instant::now(),
    };
    let (conn, mut control, mut up, hello) = match handshake(endpoint, wait).await {
        Ok(x) => x,
        Err(e) => {
            run.record(&HELLO, Err(e));
            return run.report;
        }
    };
    run.record(&HELLO, Ok(()));
    // zstd when the client decodes it: the exact-limit case pads with a
    // skippable frame.
    let zstd = hello.compressions & 0b100 != 0;
    let welcome = Welcome {
        version: 1,
        compression: if zstd { 2 } else { 0 },
        point_format: 0,
        // Limits at the client's exact offer.
        max_frame_bytes: hello.max_frame_bytes,
        max_payload_bytes: hello.max_payload_bytes,
        frame_rate: 60,
        culling: false,
        overflow: false,
        digest: hello.digest,
        scene: "conformance".into(),
    };
    let opened = async {
        control
            .write_all(&Control::Welcome(welcome).to_bytes())
            .await
            .map_err(|e| e.to_string())?;
        conn.open_uni()
            .await
            .map_err(|e| format!("cannot open the frame stream (does the client allow one?): {e}"))
    }
    .await;
    let frames = match opened {
        Ok(f) => f,
        Err(e) => {
            run.record(&JOIN, Err(e));
            return run.report;
        }
    };
    let mut s = Script::new(frames, control);
    let (s, up) = (&mut s, &mut up);

    // A late join: the state moves on before the client's first keyframe.
    let r = async {
        for _ in 0..3 {
            s.delta()?;
        }
        keyframe_acked(s, up, "ACK of the keyframe (a SHOULD)").await
    }
    .await;
    run.record(&JOIN, r);

    // A delta is skipped: the client asks with reason 0.
    let r = async {
        for _ in 0..3 {
            let d = s.delta()?;
            s.send(&d.bytes).await?;
        }
        let _skipped = s.delta()?;
        let d = s.delta()?;
        s.send(&d.bytes).await?;
        answered(s, up, KeyframeReason::Gap).await
    }
    .await;
    run.record(&GAP, r);

    // A frame whose checksum fails: reason 1.
    let r = async {
        let d = s.delta()?;
        let mut bad = d.bytes.to_vec();
        let last = bad.len() - 1;
        bad[last] ^= 0x40;
        s.send(&bad).await?;
        answered(s, up, KeyframeReason::DecodeError).await
    }
    .await;
    run.record(&CORRUPT, r);

    // NOTICE 2, then a keyframe well ahead, without a request.
    let r = async {
        for _ in 0..20 {
            s.delta()?;
        }
        s.control(Control::Notice {
            code: NoticeCode::FellBehind,
            text: "fell behind; resynchronizing with a keyframe".into(),
        })
        .await?;
        keyframe_acked(s, up, "ACK of the keyframe after the jump").await
    }
    .await;
    run.record(&RESYNC, r);

    // Every code, an unknown one included, closes nothing: the client is
    // still there to acknowledge the next keyframe.
    let r = async {
        for (code, text) in [
            (NoticeCode::EventRefused, "refused"),
            (NoticeCode::Other(3), "other"),
            (NoticeCode::BelowRate, "41.5 of 60 Hz"),
            (NoticeCode::Other(200), "a code from the future"),
        ] {
            s.control(Control::Notice {
                code,
                text: text.into(),
            })
            .await?;
        }
        keyframe_acked(s, up, "ACK after the notices").await
    }
    .await;
    run.record(&NOTICES, r);

    // A frame of exactly the client's max_frame_bytes (a zstd payload
    // padded with a skippable frame), then a delta and a keyframe: no
    // request may come, the keyframe is acknowledged.
    let r = async {
        if !zstd {
            return Err("SKIP:the client does not decode zstd, which the padding needs".into());
        }
        let d = s.delta()?;
        let big = exact_frame(&d.bytes, hello.max_frame_bytes)?;
        s.send(&big).await?;
        let next = s.delta()?;
        s.send(&next.bytes).await?;
        let kf = s.keyframe()?;
        s.send(&kf.bytes).await?;
        let m = up
            .expect(
                Duration::from_secs(10),
                "ACK of the keyframe after the full-size frame",
                |m| {
                    matches!(m, Control::Ack(a) if *a == kf.sequence)
                        || matches!(m, Control::KeyframeRequest { .. })
                },
            )
            .await?;
        match m {
            Control::KeyframeRequest { reason, .. } => Err(format!(
                "the client refused the {}-byte frame (a keyframe request, reason {reason:?})",
                big.len()
            )),
            _ => Ok(()),
        }
    }
    .await;
    run.record(&LIMIT, r);

    // A wrong DIGEST for the frame that follows it: reason 4.
    let r = async {
        if !hello.digest {
            return Err("SKIP:the client does not check digests (HELLO.flags.digest is 0)".into());
        }
        let d = s.delta()?;
        s.control(Control::Digest {
            sequence: d.sequence,
            digest: 0x0BAD_D1CE,
        })
        .await?;
        s.send(&d.bytes).await?;
        answered(s, up, KeyframeReason::DigestMismatch).await
    }
    .await;
    run.record(&DIGEST, r);

    // The frame stream finishes and the server closes; the client must
    // not have closed on its own before.
    let r = async {
        s.frames.finish().map_err(|e| e.to_string())?;
        tokio::time::sleep(Duration::from_millis(200)).await;
        match conn.close_reason() {
            Some(quinn::ConnectionError::ApplicationClosed(c))
                if c.error_code.into_inner() != 0 =>
            {
                Err(format!(
                    "the client closed with code {} before the shutdown",
                    c.error_code
                ))
            }
            _ => Ok(()),
        }
    }
    .await;
    conn.close(
        psao_proto::CloseCode::ServerShutdown.code().into(),
        b"conformance run over",
    );
    run.record(&SHUTDOWN, r);
    run.report
}
