//! Server and clients over loopback QUIC: many clients in sync, a late
//! joiner, a client that stops reading (bounded server memory), one that
//! vanishes without closing, a lossy reordering link, and clients sending
//! malformed or oversized messages, which are closed with the specified
//! code while the others keep being served.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering::SeqCst};
use std::time::Duration;

use glam::{Affine3A, Vec3};
use psao_proto::control::{Control, Hello};
use psao_proto::tls::client_config;
use psao_proto::*;
use psao_scene::{Pipeline, PipelineConfig, ViewerCull};
use psao_tests::relay::{Impairment, Relay};
use psao_tests::scenes::{pipeline_config, sliding_box};

fn config(max_queue_bytes: usize) -> ServerConfig {
    ServerConfig {
        max_queue_bytes,
        idle_timeout: Duration::from_secs(2),
        ..ServerConfig::default()
    }
}

/// The sliding-box scene's pipeline at 64 points per square metre and 8
/// rays per point, culling as `cull` says.
fn source(cull: Option<ViewerCull>) -> Pipeline {
    let config = PipelineConfig {
        cull,
        ..pipeline_config(64.0, 8)
    };
    Pipeline::new(sliding_box(), config).expect("the pipeline builds")
}

async fn client<S: FrameSource>(
    server: &ServerHandle<S>,
    addr: Option<std::net::SocketAddr>,
) -> ClientHandle {
    connect(
        addr.unwrap_or(server.local_addr()),
        &Trust::Fingerprint(server.fingerprint()),
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await
    .expect("connects")
}

/// Whether the client's mirror equals the server's tables.
fn in_sync(c: &ClientHandle, p: &Pipeline) -> bool {
    c.with_session(|s| {
        (0..p.instance_count()).all(|i| {
            let t = p.table(i).unwrap();
            s.mirror()
                .instance(i as u32)
                .is_some_and(|m| m.words() == t.words() && m.buckets() == t.buckets())
        })
    })
}

/// A bare QUIC connection that has sent `HELLO` and read `WELCOME`, for
/// clients that misbehave. Its streams accept at most 4 KiB unread.
async fn raw(
    server: &ServerHandle<Pipeline>,
) -> (
    quinn::Endpoint,
    quinn::Connection,
    (quinn::SendStream, quinn::RecvStream),
) {
    raw_to(server.local_addr(), server.fingerprint()).await
}

/// [`raw`] to any server.
async fn raw_to(
    addr: std::net::SocketAddr,
    fingerprint: [u8; 32],
) -> (
    quinn::Endpoint,
    quinn::Connection,
    (quinn::SendStream, quinn::RecvStream),
) {
    let hello = Control::Hello(Hello {
        version: 1,
        compressions: 0b111,
        point_formats: 1,
        max_frame_bytes: 1 << 26,
        max_payload_bytes: 1 << 26,
        max_mirror_bytes: 1 << 30,
        viewer: false,
        overflow: true,
        digest: false,
    });
    let (ep, conn, (send, mut recv)) = raw_hello(addr, fingerprint, &hello.to_bytes()).await;
    let body = read_control(&mut recv).await.expect("WELCOME");
    assert_eq!(body[0], 0x02, "WELCOME");
    // The control stream stays open both ways (dropping the receiving
    // half would stop the server's sending half: a violation of its own).
    (ep, conn, (send, recv))
}

/// A bare QUIC connection that has opened its control stream and written
/// `hello` (any bytes) on it.
async fn raw_hello(
    addr: std::net::SocketAddr,
    fingerprint: [u8; 32],
    hello: &[u8],
) -> (
    quinn::Endpoint,
    quinn::Connection,
    (quinn::SendStream, quinn::RecvStream),
) {
    let mut ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let mut cc = client_config(&Trust::Fingerprint(fingerprint)).unwrap();
    let mut transport = quinn::TransportConfig::default();
    transport.stream_receive_window(4096u32.into());
    transport.receive_window(8192u32.into());
    cc.transport_config(std::sync::Arc::new(transport));
    ep.set_default_client_config(cc);
    let conn = ep.connect(addr, "localhost").unwrap().await.unwrap();
    let (mut send, recv) = conn.open_bi().await.unwrap();
    send.write_all(hello).await.unwrap();
    (ep, conn, (send, recv))
}

/// The next control message's type and body; `None` once the stream or
/// connection ends.
async fn read_control(recv: &mut quinn::RecvStream) -> Option<Vec<u8>> {
    let mut len = [0u8; 2];
    recv.read_exact(&mut len).await.ok()?;
    let mut body = vec![0u8; u16::from_le_bytes(len) as usize];
    recv.read_exact(&mut body).await.ok()?;
    Some(body)
}

/// The application close code and reason of a connection.
async fn close_of(conn: &quinn::Connection) -> (CloseCode, String) {
    match tokio::time::timeout(Duration::from_secs(10), conn.closed()).await {
        Ok(quinn::ConnectionError::ApplicationClosed(c)) => (
            CloseCode::from_code(c.error_code.into_inner()),
            String::from_utf8_lossy(&c.reason).into_owned(),
        ),
        other => panic!("not closed by the application: {other:?}"),
    }
}

/// The HELLO example of spec/session.md section 8, as bytes.
fn spec_example(name: &str) -> Vec<u8> {
    let spec = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../spec/session.md"))
        .unwrap();
    let mut lines = spec.lines().skip_while(|l| *l != format!("```hex {name}"));
    lines.next().expect("the example");
    lines
        .take_while(|l| !l.starts_with("```"))
        .flat_map(|l| l.split_whitespace())
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// spec/session.md 3.2 (issue 16, finding 1): the spec's own example
/// HELLO (1 MiB limits) is accepted, and WELCOME answers with its limits;
/// a HELLO whose limits are below the largest frame the server has sent
/// is refused with `capability_mismatch` and a reason naming that size.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hello_limits_are_accepted_when_the_frames_fit_and_refused_naming_the_size() {
    let id = Identity::self_signed().unwrap();
    let server = serve(Bulky::new(80 * 1024, 0), config(1 << 20), &id)
        .await
        .unwrap();
    let hello = spec_example("HELLO");
    assert_eq!(hello[11..15], (1u32 << 20).to_le_bytes(), "a 1 MiB offer");
    let (_ep, conn, (_send, mut recv)) =
        raw_hello(server.local_addr(), server.fingerprint(), &hello).await;
    let welcome = read_control(&mut recv).await.expect("WELCOME, not a close");
    assert_eq!(welcome[0], 0x02);
    assert_eq!(welcome[5..9], (1u32 << 20).to_le_bytes(), "max_frame_bytes");
    assert_eq!(
        welcome[9..13],
        (1u32 << 20).to_le_bytes(),
        "max_payload_bytes"
    );
    let mut frames = conn.accept_uni().await.unwrap();
    let got = read_frames(&mut frames, Duration::from_millis(200)).await;
    assert!(
        got.first().is_some_and(|f| f.1),
        "a keyframe first: {got:?}"
    );
    // The server has sent 80 KiB frames: a client accepting 64 KiB (the
    // spec's minimum) cannot follow it.
    let mut small = hello.clone();
    small[11..15].copy_from_slice(&65_536u32.to_le_bytes());
    small[15..19].copy_from_slice(&65_536u32.to_le_bytes());
    let (_ep2, conn2, _streams) =
        raw_hello(server.local_addr(), server.fingerprint(), &small).await;
    let (code, reason) = close_of(&conn2).await;
    assert_eq!(code, CloseCode::CapabilityMismatch, "{reason}");
    let largest = server.stats().largest_frame;
    assert!(largest > 80 * 1024, "{largest}");
    assert!(
        reason.contains(&largest.to_string()),
        "the reason names the size: {reason}"
    );
}

/// Frames that outgrow a client's limits after it joined are not sent to
/// it: a delta above them is skipped and the client resynchronized with
/// a keyframe and NOTICE 2; a keyframe above them closes it with
/// `capability_mismatch`, naming the size.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_above_a_clients_limits_are_never_sent_to_it() {
    let id = Identity::self_signed().unwrap();
    let source = Bulky::new(1024, 0);
    let (deltas, keyframes) = (source.delta_bytes.clone(), source.keyframe_bytes.clone());
    let server = serve(source, config(1 << 20), &id).await.unwrap();
    let mut hello = spec_example("HELLO");
    hello[11..15].copy_from_slice(&65_536u32.to_le_bytes());
    hello[15..19].copy_from_slice(&65_536u32.to_le_bytes());
    let (_ep, conn, (_send, mut recv)) =
        raw_hello(server.local_addr(), server.fingerprint(), &hello).await;
    let welcome = read_control(&mut recv).await.expect("WELCOME");
    assert_eq!(welcome[5..9], 65_536u32.to_le_bytes());
    let mut frames = conn.accept_uni().await.unwrap();
    let mut sizes = Vec::new();
    let mut read = async |frames: &mut quinn::RecvStream, time| {
        let end = std::time::Instant::now() + time;
        while std::time::Instant::now() < end {
            let mut len = [0u8; 4];
            if frames.read_exact(&mut len).await.is_err() {
                break;
            }
            let mut frame = vec![0u8; u32::from_le_bytes(len) as usize];
            frames.read_exact(&mut frame).await.unwrap();
            sizes.push((frame.len(), frame[5] & 1 == 1));
        }
    };
    read(&mut frames, Duration::from_millis(200)).await;
    // Deltas grow past 64 KiB for a while, then shrink again.
    deltas.store(70 * 1024, SeqCst);
    tokio::time::sleep(Duration::from_millis(200)).await;
    deltas.store(1024, SeqCst);
    read(&mut frames, Duration::from_millis(300)).await;
    assert!(sizes.iter().all(|s| s.0 <= 65_536), "{sizes:?}");
    let resyncs = sizes.iter().skip(1).filter(|s| s.1).count();
    assert!(
        resyncs >= 1,
        "resynchronized after the skipped deltas: {sizes:?}"
    );
    let notice = read_control(&mut recv).await.expect("NOTICE");
    assert_eq!((notice[0], notice[1]), (0x20, 2), "NOTICE code 2");
    // Now keyframes outgrow it too: the next one it needs closes it.
    keyframes.store(70 * 1024, SeqCst);
    deltas.store(70 * 1024, SeqCst);
    let (code, reason) = close_of(&conn).await;
    assert_eq!(code, CloseCode::CapabilityMismatch, "{reason}");
    assert!(reason.contains("keyframe of 7"), "{reason}");
    assert!(reason.contains("65536"), "{reason}");
    drop(server);
}

/// spec/session.md 6 (issue 16, finding 3): 300 messages in one write are
/// `rate_exceeded`, every time, even when the client also stops the
/// frame stream at once (a second violation the writer sees, which used
/// to close first with `protocol_violation` "a stream was stopped").
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_close_code_of_a_violation_is_deterministic() {
    let id = Identity::self_signed().unwrap();
    let server = serve(Bulky::new(8 * 1024, 0), config(1 << 20), &id)
        .await
        .unwrap();
    let acks: Vec<u8> = (0..300u32)
        .flat_map(|s| Control::Ack(s).to_bytes().to_vec())
        .collect();
    for run in 0..12 {
        let (_ep, conn, (mut send, _recv)) =
            raw_to(server.local_addr(), server.fingerprint()).await;
        let mut frames = conn.accept_uni().await.unwrap();
        send.write_all(&acks).await.unwrap();
        // Also a violation: a stream stopped, or a second stream opened.
        if run % 2 == 0 {
            let _ = frames.stop(0u32.into());
        } else {
            if let Ok(mut extra) = conn.open_uni().await {
                let _ = extra.write_all(&[0]).await;
            }
        }
        let (code, reason) = close_of(&conn).await;
        assert_eq!(code, CloseCode::RateExceeded, "run {run}: {reason}");
    }
}

async fn close_code(conn: &quinn::Connection) -> CloseCode {
    close_of(conn).await.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_clients_late_slow_vanishing_and_misbehaving() {
    let id = Identity::self_signed().unwrap();
    let queue = 4 * 1024;
    let server = serve(source(None), config(queue), &id).await.unwrap();
    let mut good = Vec::new();
    for _ in 0..3 {
        good.push(client(&server, None).await);
    }
    // A client that stops reading its frames.
    let (_slow_ep, slow, _slow_send) = raw(&server).await;
    let _frames = slow.accept_uni().await.unwrap();
    // A client behind a relay that will vanish.
    let relay = Relay::start(server.local_addr(), Impairment::default())
        .await
        .unwrap();
    let vanishing = client(&server, Some(relay.addr())).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    // A late joiner.
    good.push(client(&server, None).await);
    assert!(good[3].with_session(|s| s.stats().keyframes) <= 1);
    // Misbehaving clients: an unknown message type, and an oversized one.
    let (_ep1, bad1, mut ctl1) = raw(&server).await;
    ctl1.0.write_all(&[1, 0, 0x7f]).await.unwrap();
    let (_ep2, bad2, mut ctl2) = raw(&server).await;
    ctl2.0.write_all(&[0xff, 0x7f]).await.unwrap();
    assert_eq!(close_code(&bad1).await, CloseCode::ProtocolViolation);
    assert_eq!(close_code(&bad2).await, CloseCode::MessageTooLarge);
    // The vanishing client goes quiet without closing.
    relay.cut(true);
    let joined = server.stats().clients;
    let mut most_queued = 0;
    for _ in 0..30 {
        tokio::time::sleep(Duration::from_millis(100)).await;
        most_queued = most_queued.max(server.stats().max_queued);
    }
    // It is dropped after the idle timeout (2 s).
    let mut left = false;
    for _ in 0..40 {
        if server.stats().clients < joined {
            left = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(left, "the vanished client was dropped");
    let stats = server.stats();
    assert!(stats.falls > 0, "the stalled client fell behind: {stats:?}");
    // A stalled client costs at most the queue bound plus one keyframe.
    let keyframe = 64 * 1024;
    assert!(most_queued <= queue + keyframe, "{most_queued}");
    let (pipeline, end) = server.shutdown(Duration::from_secs(3)).await.unwrap();
    for (k, c) in good.iter().enumerate() {
        let reached = c
            .wait_for(Duration::from_secs(5), |s| {
                s.mirror().sequence() == Some(end.sequence)
            })
            .await;
        assert!(reached, "client {k} reached the last sequence");
        assert!(in_sync(c, &pipeline), "client {k} mirrors the server");
        let s = c.with_session(|s| s.stats());
        assert_eq!(s.failed, 0, "client {k}: {s:?}");
        // Digests (spec/session.md 3.8, every 60th frame) confirmed it.
        assert!(s.digests_matched > 0, "client {k}: {s:?}");
        assert_eq!(s.digest_mismatches, 0, "client {k}: {s:?}");
    }
    // Encoded once: the bytes written to clients are a multiple of the
    // bytes encoded, not re-encoded per client.
    assert!(end.written_bytes > 3 * end.encoded_bytes);
    drop(vanishing);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lossy_reordering_link_keeps_the_stream_consistent() {
    let id = Identity::self_signed().unwrap();
    let server = serve(source(None), config(1 << 20), &id).await.unwrap();
    let relay = Relay::start(
        server.local_addr(),
        Impairment {
            drop: 0.05,
            delay: Duration::from_millis(5),
            jitter: Duration::from_millis(50),
            seed: 7,
        },
    )
    .await
    .unwrap();
    let c = client(&server, Some(relay.addr())).await;
    let direct = client(&server, None).await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(relay.dropped() > 0, "the relay dropped datagrams");
    let (pipeline, end) = server.shutdown(Duration::from_secs(5)).await.unwrap();
    for c in [&c, &direct] {
        assert!(
            c.wait_for(Duration::from_secs(10), |s| s.mirror().sequence()
                == Some(end.sequence))
                .await
        );
        assert!(in_sync(c, &pipeline));
        assert_eq!(c.with_session(|s| s.stats().failed), 0);
    }
    // Both see the server's shutdown as such (not as a protocol error).
    for c in [&c, &direct] {
        c.wait_for(Duration::from_secs(5), |_| false).await;
        match c.ended() {
            Ended::Closed(close) => assert_eq!(close.code, CloseCode::ServerShutdown, "{close}"),
            Ended::Running => panic!("still running after shutdown"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scene_events_move_instances_for_everyone() {
    let id = Identity::self_signed().unwrap();
    let server = serve(source(None), config(1 << 20), &id).await.unwrap();
    let a = client(&server, None).await;
    let b = client(&server, None).await;
    let to = Affine3A::from_translation(Vec3::new(0.5, 1.0, 0.5));
    a.send_move(1, to);
    // The static floor cannot move: refused with a notice.
    a.send_move(0, to);
    let moved = b
        .wait_for(Duration::from_secs(5), |s| {
            s.mirror()
                .instance(1)
                .and_then(|m| m.transform())
                .is_some_and(|t| t.affine() == to)
        })
        .await;
    assert!(moved, "the other client sees the move");
    let noticed = a
        .wait_for(Duration::from_secs(5), |s| {
            std::iter::from_fn(|| s.poll_event()).any(|e| {
                matches!(
                    e,
                    ClientEvent::Notice {
                        code: control::NoticeCode::EventRefused,
                        ..
                    }
                )
            })
        })
        .await;
    assert!(noticed, "the refusal comes back as a notice");
    server.shutdown(Duration::from_secs(1)).await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_server_says_so() {
    let id = Identity::self_signed().unwrap();
    let server = serve(
        source(None),
        ServerConfig {
            max_clients: 1,
            ..config(1 << 20)
        },
        &id,
    )
    .await
    .unwrap();
    let first = client(&server, None).await;
    let second = connect(
        server.local_addr(),
        &Trust::Fingerprint(server.fingerprint()),
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await;
    match second {
        Err(ConnectError::Closed(c)) => assert_eq!(c.code, CloseCode::ServerFull),
        other => panic!("{other:?}"),
    }
    // A client that pins another fingerprint does not connect at all.
    let wrong = connect(
        server.local_addr(),
        &Trust::Fingerprint([0; 32]),
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await;
    assert!(
        matches!(wrong, Err(ConnectError::Connect { .. })),
        "{wrong:?}"
    );
    // Dropping the handle without shutdown() still stops the server, and
    // its client hears so.
    drop(server);
    first.wait_for(Duration::from_secs(5), |_| false).await;
    match first.ended() {
        Ended::Closed(close) => assert_eq!(close.code, CloseCode::ServerShutdown, "{close}"),
        Ended::Running => panic!("still running after the server was dropped"),
    }
    first.close().await;
}

/// Points traced and culled over `wait` of serving.
async fn traced_and_culled(server: &ServerHandle<Pipeline>, wait: Duration) -> (u64, u64, u64) {
    let a = server.stats();
    tokio::time::sleep(wait).await;
    let b = server.stats();
    (
        b.report.traced - a.report.traced,
        b.report.culled - a.report.culled,
        b.frames - a.frames,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_culling_server_traces_what_its_viewers_see() {
    let id = Identity::self_signed().unwrap();
    let cull = ViewerCull {
        aspect: 1.0,
        far: 50.0,
        margin: 0.0,
    };
    let server = serve(source(Some(cull)), config(1 << 20), &id)
        .await
        .unwrap();
    let viewer = connect(
        server.local_addr(),
        &Trust::Fingerprint(server.fingerprint()),
        ClientConfig {
            viewer: true,
            ..ClientConfig::default()
        },
        Duration::from_secs(10),
    )
    .await
    .unwrap();
    let welcome = viewer.with_session(|s| s.welcome().cloned()).unwrap();
    assert!(welcome.culling, "WELCOME says the server culls");
    let pose = |eye: Vec3, target: Vec3| control::CameraPose {
        time_ms: 0,
        eye,
        target,
        fov_y: 1.0,
        aspect: 1.0,
    };
    // Looking away from the scene (it lies behind the camera): the box's
    // neighbourhood waits, nothing is traced.
    viewer.send_camera(pose(Vec3::new(0.0, 1.0, 10.0), Vec3::new(0.0, 1.0, 20.0)));
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (traced, culled, frames) = traced_and_culled(&server, Duration::from_millis(500)).await;
    assert!(frames > 5, "{frames} frames");
    assert_eq!(traced, 0, "nothing in view is traced ({culled} culled)");
    assert!(culled > 0, "points near the moving box wait");
    // Looking at it: the box's neighbourhood is traced again.
    viewer.send_camera(pose(Vec3::new(0.0, 3.0, 6.0), Vec3::ZERO));
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (traced, _, _) = traced_and_culled(&server, Duration::from_millis(500)).await;
    assert!(
        traced > 0,
        "in view, the moving box's surroundings are traced"
    );
    // Back to looking away, then a client that does not say what it sees
    // joins: the server stops culling for it.
    viewer.send_camera(pose(Vec3::new(0.0, 1.0, 10.0), Vec3::new(0.0, 1.0, 20.0)));
    let blind = client(&server, None).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (traced, culled, _) = traced_and_culled(&server, Duration::from_millis(500)).await;
    assert!(traced > 0, "a non-viewer sees everything ({culled} culled)");
    assert_eq!(culled, 0);
    drop(blind);
    let p = server.shutdown(Duration::from_secs(1)).await.unwrap().0;
    assert!(
        in_sync(&viewer, &p),
        "the viewer's mirror still equals the tables"
    );
}

/// A pipeline whose every step takes at least `delay`: a server too slow
/// for the rate it announces.
struct Slow {
    inner: Pipeline,
    delay: Duration,
}

impl FrameSource for Slow {
    fn info(&self) -> SourceInfo {
        self.inner.info()
    }
    fn step(
        &mut self,
        dt: f32,
    ) -> Result<(Option<psao_codec::EncodedFrame>, StepReport), SourceError> {
        std::thread::sleep(self.delay);
        FrameSource::step(&mut self.inner, dt)
    }
    fn keyframe(&mut self) -> Result<psao_codec::EncodedFrame, SourceError> {
        FrameSource::keyframe(&mut self.inner)
    }
    fn place(&mut self, instance: u32, transform: Affine3A) -> Result<(), SourceError> {
        FrameSource::place(&mut self.inner, instance, transform)
    }
}

/// Whether `c` gets a below-rate notice within `wait`; its text.
async fn rate_notice(c: &ClientHandle, wait: Duration) -> Option<String> {
    let mut text = None;
    c.wait_for(wait, |s| {
        for e in std::iter::from_fn(|| s.poll_event()) {
            if let ClientEvent::Notice {
                code: control::NoticeCode::BelowRate,
                text: t,
            } = e
            {
                text = Some(t);
            }
        }
        text.is_some()
    })
    .await;
    text
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_below_its_announced_rate_tells_its_clients() {
    let id = Identity::self_signed().unwrap();
    // 60 Hz announced, at most 1 / 40 ms = 25 Hz delivered.
    let slow = Slow {
        inner: source(None),
        delay: Duration::from_millis(40),
    };
    let server = serve(slow, config(1 << 20), &id).await.unwrap();
    let c = client(&server, None).await;
    let text = rate_notice(&c, Duration::from_secs(6)).await;
    let text = text.expect("a below-rate notice");
    let hz: f64 = text.split(' ').next().unwrap().parse().unwrap();
    assert!(hz < 54.0 && text.ends_with("of 60 Hz"), "{text}");
    let stats = server.stats();
    assert!(stats.rate_notices >= 1);
    // Always behind: every tick starts at once, and ticks more than
    // rate::CATCH_UP behind are given up.
    assert!(stats.behind_ticks > 0 && stats.lost_ticks > 0, "{stats:?}");
    server.shutdown(Duration::from_secs(1)).await.unwrap();
    // A server that keeps its rate (5 Hz, a light scene: a tick would
    // have to be 250 ms late to be lost) says nothing.
    let server = serve(
        source(None),
        ServerConfig {
            frame_rate: 5,
            ..config(1 << 20)
        },
        &id,
    )
    .await
    .unwrap();
    let c = client(&server, None).await;
    assert_eq!(rate_notice(&c, Duration::from_secs(3)).await, None);
    assert_eq!(server.stats().rate_notices, 0);
    server.shutdown(Duration::from_secs(1)).await.unwrap();
}

/// A source of large frames (deltas and keyframes padded with repeated
/// transforms to the sizes its handles say), so that a stalled client
/// fills the QUIC send window within a second, and frames can outgrow a
/// client's limits mid-session.
#[derive(Clone, Default)]
struct Bulky {
    sequence: u32,
    delta_bytes: Arc<AtomicUsize>,
    keyframe_bytes: Arc<AtomicUsize>,
}

impl Bulky {
    fn new(delta_bytes: usize, keyframe_bytes: usize) -> Bulky {
        Bulky {
            sequence: 1,
            delta_bytes: Arc::new(delta_bytes.into()),
            keyframe_bytes: Arc::new(keyframe_bytes.into()),
        }
    }

    fn frame(&self, keyframe: bool) -> psao_codec::EncodedFrame {
        use psao_tests::raw;
        let s = self.sequence;
        let pad = |bytes: &AtomicUsize| vec![raw::transform(1, s, 1.0); bytes.load(SeqCst) / 53];
        let messages: Vec<Vec<u8>> = if keyframe {
            [vec![raw::define(1, &raw::DEF)], pad(&self.keyframe_bytes)].concat()
        } else {
            pad(&self.delta_bytes)
        };
        psao_codec::EncodedFrame {
            bytes: raw::frame(keyframe, s, s.wrapping_sub(1), &messages).into(),
            sequence: s,
            keyframe,
            stats: Default::default(),
        }
    }
}

impl FrameSource for Bulky {
    fn info(&self) -> SourceInfo {
        SourceInfo {
            compression: 0,
            max_frame_bytes: 1 << 24,
            max_payload_bytes: 1 << 24,
            mirror_bytes: 1 << 20,
            point_format: 0,
            overflow: false,
            culls: false,
        }
    }
    fn step(
        &mut self,
        _dt: f32,
    ) -> Result<(Option<psao_codec::EncodedFrame>, StepReport), SourceError> {
        self.sequence += 1;
        Ok((Some(self.frame(false)), StepReport::default()))
    }
    fn keyframe(&mut self) -> Result<psao_codec::EncodedFrame, SourceError> {
        Ok(self.frame(true))
    }
    fn place(&mut self, _: u32, _: Affine3A) -> Result<(), SourceError> {
        Err("no events".into())
    }
}

/// Reads whole frame records off `frames` for `time` (checked between
/// records, so none is cut), returning each frame's (sequence, keyframe).
async fn read_frames(frames: &mut quinn::RecvStream, time: Duration) -> Vec<(u32, bool)> {
    let end = std::time::Instant::now() + time;
    let mut got = Vec::new();
    while std::time::Instant::now() < end {
        let mut len = [0u8; 4];
        if frames.read_exact(&mut len).await.is_err() {
            break;
        }
        let mut frame = vec![0u8; u32::from_le_bytes(len) as usize];
        if frames.read_exact(&mut frame).await.is_err() {
            break;
        }
        let h = psao_codec::wire::FrameHeader::parse(&frame).unwrap();
        got.push((h.sequence, h.keyframe));
    }
    got
}

/// spec/session.md 5.2.3: a client that fell behind gets its keyframe
/// and a `NOTICE` with code 2, however long it stalled, on a connection
/// whose flow-control window the frames fill (the notice waits for the
/// same window).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_falls_behind_gets_notice_2_with_its_keyframe() {
    let id = Identity::self_signed().unwrap();
    let server = serve(Bulky::new(16 * 1024, 0), config(16 * 1024), &id)
        .await
        .unwrap();
    let (_ep, conn, (_send, mut control)) = raw_to(server.local_addr(), server.fingerprint()).await;
    let mut frames = conn.accept_uni().await.unwrap();
    let notices = tokio::spawn(async move {
        let mut reader = control::ControlReader::new();
        let mut codes = Vec::new();
        let mut buf = [0u8; 1024];
        while let Ok(Some(n)) = control.read(&mut buf).await {
            let mut input = &buf[..n];
            while let Ok(Some(m)) = reader.read(&mut input) {
                if let Control::Notice { code, .. } = m {
                    codes.push(code);
                }
            }
        }
        codes
    });
    let mut seen = read_frames(&mut frames, Duration::from_millis(300)).await;
    // Stall twice, long enough to fall behind each time.
    for _ in 0..2 {
        tokio::time::sleep(Duration::from_millis(800)).await;
        seen.extend(read_frames(&mut frames, Duration::from_millis(500)).await);
    }
    // Shut down while reading the rest: every frame written arrives.
    let (rest, end) = tokio::join!(
        read_frames(&mut frames, Duration::from_secs(20)),
        server.shutdown(Duration::from_secs(3))
    );
    seen.extend(rest);
    let (_, stats) = end.unwrap();
    let jumps = seen
        .windows(2)
        .filter(|w| w[1].1 && w[1].0 != w[0].0.wrapping_add(1))
        .count();
    let codes = tokio::time::timeout(Duration::from_secs(5), notices)
        .await
        .expect("the control stream ends")
        .unwrap();
    let told = codes
        .iter()
        .filter(|c| **c == control::NoticeCode::FellBehind)
        .count();
    assert!(stats.falls >= 2, "the client fell behind twice: {stats:?}");
    assert_eq!(stats.resyncs as usize, jumps, "{stats:?}");
    assert!(jumps >= 2, "keyframes after jumps: {seen:?}");
    let kfs: Vec<_> = seen
        .windows(2)
        .filter(|w| w[1].1)
        .map(|w| (w[0].0, w[1].0))
        .collect();
    assert_eq!(
        told,
        jumps,
        "keyframes {kfs:?} of {} frames, notices {}, {stats:?}",
        seen.len(),
        codes.len()
    );
}

/// spec/session.md 5.1 and 2 (issue 16, finding 6): a `WELCOME` sent by a
/// client is a violation of role (`protocol_violation`), not a version
/// mismatch; a client that allows no server-initiated stream is closed
/// (it used to get WELCOME, then silence).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_breaking_the_handshake_is_closed_with_the_right_code() {
    let id = Identity::self_signed().unwrap();
    let server = serve(Bulky::new(1024, 0), config(1 << 20), &id)
        .await
        .unwrap();
    let (addr, fp) = (server.local_addr(), server.fingerprint());
    // A WELCOME from the client, first and after HELLO, with a bad version.
    let mut welcome = spec_example("WELCOME");
    welcome[3] = 9;
    let (_ep, conn, _s) = raw_hello(addr, fp, &welcome).await;
    let (code, reason) = close_of(&conn).await;
    assert_eq!(code, CloseCode::ProtocolViolation, "{reason}");
    let (_ep, conn, (mut send, _recv)) = raw_to(addr, fp).await;
    send.write_all(&welcome).await.unwrap();
    let (code, reason) = close_of(&conn).await;
    assert_eq!(code, CloseCode::ProtocolViolation, "{reason}");
    assert!(reason.contains("other role"), "{reason}");
    // No room for the frame stream: closed within the handshake timeout.
    let mut ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let mut cc = client_config(&Trust::Fingerprint(fp)).unwrap();
    let mut transport = quinn::TransportConfig::default();
    transport.max_concurrent_uni_streams(0u32.into());
    cc.transport_config(Arc::new(transport));
    ep.set_default_client_config(cc);
    let conn = ep.connect(addr, "localhost").unwrap().await.unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    send.write_all(&spec_example("HELLO")).await.unwrap();
    assert_eq!(read_control(&mut recv).await.expect("WELCOME")[0], 0x02);
    let (code, reason) = close_of(&conn).await;
    assert_eq!(code, CloseCode::ProtocolViolation, "{reason}");
    assert!(reason.contains("initial_max_streams_uni"), "{reason}");
}
