//! The whole data path in one deterministic test, without sockets: scene
//! -> points -> AO -> dirty set (the `Pipeline`) -> encoded frames -> the
//! server's sans-IO session core (`ServerConn`, `Fanout`) -> a simulated
//! link on a virtual clock -> the client's sans-IO core (`ClientSession`,
//! its decoder and mirror) -> the client's reconstructed image, compared
//! with a per-pixel ray-traced reference.
//!
//! The control streams are reliable and ordered (as QUIC streams are). Frame
//! records travel as units that are lost 5% of the time and overtake each
//! other (as over datagrams or a relay that drops groups): every loss
//! shows up as a gap the client must resynchronize from with a keyframe
//! request. For a second the link is congested, so the client's outbox
//! overflows and it falls behind. After the run, the link heals and
//! drains: the client's mirror must equal the server's tables, word for
//! word, and its image must be as close to the reference as a lossless
//! client's is (it is the same image). The same seed gives the same run.

use std::time::{Duration, Instant};

use bytes::{BufMut, BytesMut};
use glam::Vec3;
use psao_codec::Limits;
use psao_eval::{PosedScene, View, psao_image, ray_traced_ao, rmse};
use psao_proto::control::NoticeCode;
use psao_proto::records::record_prefix;
use psao_proto::{
    ClientConfig, ClientEvent, ClientSession, Fanout, FrameSource, Keyframes, Offer, ServerConn,
    ServerEvent, Transmit,
};
use psao_scene::{AoParams, Camera, Pipeline, Scene};
use psao_tests::scenes::{pipeline_config, sliding_box};
use psao_tests::sim::{LinkModel, SimLink};

/// Server ticks per second (the virtual clock steps by one tick).
const RATE: u16 = 60;
/// Ticks streamed while the link misbehaves (4 s of scene time): lossy
/// and reordering for 1.5 s, congested for 1 s, lossy again for 1.5 s.
const TICKS: u32 = 240;
/// Rays per pixel of the reference image.
const REFERENCE_RAYS: u32 = 256;
/// Bound on the RMSE of the client's AO image against the ray-traced
/// reference, over the covered pixels of a 64x48 view of the sliding box
/// at 64 points per square metre and 16 rays per point. Measured: 0.015
/// (seed 7). PSAO at this density and these few rays is not the
/// reference; the bound, twice that, says how far from it the client may
/// be. A lossless client's image is the same, since the mirror is.
const RMSE_BOUND: f64 = 0.03;

/// What a run did.
#[derive(Clone, Debug, PartialEq)]
struct Run {
    /// The client's counters.
    applied: u64,
    keyframes: u64,
    requests: u64,
    /// Gaps the client saw.
    gaps: u64,
    /// `NOTICE fell_behind` the client got.
    fell_behind: u64,
    /// Digests the client checked and found equal, and found different.
    digests_matched: u64,
    digest_mismatches: u64,
    /// Times the server's fan-out saw the client fall behind.
    falls: u64,
    /// Keyframes the fan-out handed out to resynchronize it (each with
    /// its notice; a fall that drops a waiting resync keyframe makes one).
    resyncs: u64,
    /// Frame records lost and overtaken on the way down.
    lost: u64,
    overtaken: u64,
}

/// Streams the sliding-box scene to one client over the simulated link
/// seeded with `seed`, heals the link, drains it, checks that the mirror
/// equals the server's tables and renders the client's image.
fn run(seed: u64) -> (Run, Vec<f32>, Pipeline, Scene) {
    let scene = sliding_box();
    let mut pipeline = Pipeline::new(scene.clone(), pipeline_config(64.0, 16)).unwrap();
    let info = FrameSource::info(&pipeline);
    let offer = Offer {
        compression: info.compression,
        max_frame_bytes: info.max_frame_bytes,
        max_payload_bytes: info.max_payload_bytes,
        largest_frame: 0,
        largest_payload: 0,
        mirror_bytes: info.mirror_bytes,
        point_format: info.point_format,
        overflow: info.overflow,
        frame_rate: RATE,
        scene: "sliding-box".into(),
        culling: info.culls,
        digest: true,
    };
    // The server's mirror of its own stream, for digests (as the
    // reference server keeps one).
    let mut own = psao_codec::Decoder::new(Limits::default());
    // The virtual clock: one instant read once, then only added to.
    let t0 = Instant::now();
    let tick = Duration::from_secs_f64(1.0 / RATE as f64);
    let mut now = t0;
    let mut server = ServerConn::new(offer, now);
    // A small outbox (1 KiB of deltas), so that congestion makes the
    // client fall behind.
    let mut fanout = Fanout::new(1 << 10);
    let mut client = ClientSession::new(ClientConfig {
        limits: Limits::default(),
        ..ClientConfig::default()
    });
    let latency = Duration::from_millis(20);
    let mut up = SimLink::new(LinkModel::reliable(latency, 1e6), seed ^ 1);
    let mut control_down = SimLink::new(LinkModel::reliable(latency, 1e6), seed ^ 2);
    let lossy = LinkModel {
        latency,
        jitter: Duration::from_millis(20),
        loss: 0.05,
        bandwidth: 2e6,
    };
    let mut frames_down = SimLink::new(lossy, seed ^ 3);
    let mut id = None;
    let mut events = Vec::new();
    let (mut gaps, mut fell_behind) = (0, 0);
    let mut last_sequence = None;
    for k in 0..TICKS + 5 * RATE as u32 {
        // Congested from 1.5 s to 2.5 s: 2 kB/s against about 7 kB/s of
        // deltas (and a 3.5 kB keyframe), no loss. After TICKS the link
        // heals (no loss, no jitter) so that everything sent arrives.
        let t = k as f64 / RATE as f64;
        frames_down.model = if k >= TICKS {
            LinkModel::reliable(latency, 2e6)
        } else if (1.5..2.5).contains(&t) {
            LinkModel::reliable(latency, 2e3)
        } else {
            lossy
        };
        // Client -> server: HELLO, ACKs, keyframe requests.
        if let Some(b) = client.take_transmit() {
            up.send(now, b);
        }
        for b in up.deliver(now) {
            server.on_control(&b, now, &mut events).unwrap();
        }
        for ev in events.drain(..) {
            match ev {
                ServerEvent::Welcomed { bytes, viewer } => {
                    control_down.send(now, bytes);
                    let c = fanout.add_client(viewer);
                    if server.hello().is_some_and(|h| h.digest) {
                        fanout.set_digests(c, 8);
                    }
                    id = Some(c);
                }
                ServerEvent::KeyframeRequested(_) => {
                    fanout.request_keyframe(id.expect("welcomed first"));
                }
                _ => {}
            }
        }
        // The server ticks: step while streaming, then hold still; share
        // a keyframe with whoever needs one.
        if k < TICKS {
            let (frame, _) = pipeline.step(1.0 / RATE as f32).unwrap();
            if let Some(f) = frame {
                let _ = own.receive(&f.bytes);
                let digest = fanout
                    .wants_digest(false, None)
                    .then(|| own.mirror().digest())
                    .flatten();
                fanout.push_frame_with_digest(&f, digest);
                last_sequence = Some(f.sequence);
            }
        }
        if fanout.serve_keyframes() == Keyframes::Encode {
            let kf = pipeline.keyframe().unwrap();
            last_sequence = Some(kf.sequence);
            own.receive(&kf.bytes).unwrap();
            let digest = fanout
                .wants_digest(true, None)
                .then(|| own.mirror().digest())
                .flatten();
            fanout.push_keyframe_with_digest(&kf, digest);
        }
        // The writer: notices on the control stream, frames as records
        // while the link takes them.
        if let Some(c) = id {
            while frames_down.is_free(now) {
                let Some(Transmit { notices, frame, .. }) = fanout.poll_transmit(c) else {
                    break;
                };
                for n in notices {
                    control_down.send(now, n);
                }
                let Some(f) = frame else { break };
                let mut record = BytesMut::with_capacity(4 + f.len());
                record.put_slice(&record_prefix(&f));
                record.put_slice(&f);
                frames_down.send(now, record.freeze());
            }
        }
        // Server -> client.
        for b in control_down.deliver(now) {
            client.on_control(&b).unwrap();
        }
        for b in frames_down.deliver(now) {
            client.on_frames(&b).unwrap();
        }
        client.handle_timeout(now).unwrap();
        while let Some(ev) = client.poll_event() {
            match ev {
                ClientEvent::Gap { .. } => gaps += 1,
                ClientEvent::Notice {
                    code: NoticeCode::FellBehind,
                    ..
                } => fell_behind += 1,
                ClientEvent::DecodeFailed(e) => panic!("a frame failed to decode: {e}"),
                _ => {}
            }
        }
        // Once healed and drained, the client holds the last state.
        if k >= TICKS
            && frames_down.is_idle()
            && client.mirror().sequence() == last_sequence
            && fanout.queued_bytes(id.unwrap()) == 0
        {
            break;
        }
        now += tick;
    }
    assert_eq!(
        client.mirror().sequence(),
        last_sequence,
        "the client caught up with the server's last frame"
    );
    for i in 0..pipeline.instance_count() {
        let t = pipeline.table(i).unwrap();
        let m = client
            .mirror()
            .instance(i as u32)
            .expect("instance mirrored");
        assert_eq!(m.words(), t.words(), "instance {i}: the mirror's words");
        assert_eq!(
            m.buckets(),
            t.buckets(),
            "instance {i}: the mirror's buckets"
        );
    }
    let posed = PosedScene::new(&scene, pipeline.time()).unwrap();
    let image = psao_image(client.mirror(), &posed.gbuffer(&view())).unwrap();
    assert_eq!(image.unknown, 0, "every covered pixel's instance is known");
    let s = client.stats();
    let run = Run {
        applied: s.applied,
        keyframes: s.keyframes,
        requests: s.requests,
        gaps,
        fell_behind,
        digests_matched: s.digests_matched,
        digest_mismatches: s.digest_mismatches,
        falls: fanout.falls(),
        resyncs: fanout.resyncs(),
        lost: frames_down.lost,
        overtaken: frames_down.overtaken,
    };
    (run, image.ao, pipeline, scene)
}

/// A 64x48 view of the floor and the box from above and in front.
fn view() -> View {
    let camera = Camera {
        eye: Vec3::new(0.0, 2.5, 4.0),
        target: Vec3::new(0.0, 0.2, 0.0),
        fov_y: 0.9,
    };
    View::new(camera, 64, 48).unwrap()
}

#[test]
fn scene_to_pixels_over_a_lossy_reordering_congested_link() {
    let (a, image, pipeline, scene) = run(7);
    // The link did what it was meant to: the run exercised resync.
    assert!(a.lost > 0 && a.overtaken > 0, "{a:?}");
    assert!(a.gaps > 0, "losses show up as gaps");
    assert!(
        a.requests > 0 && a.keyframes > 1,
        "gaps are healed by keyframes"
    );
    assert!(a.falls > 0, "congestion makes the client fall behind");
    // Digests (spec/session.md 3.8) confirm the mirror along the way.
    assert!(a.digests_matched >= 3, "{a:?}");
    assert_eq!(a.digest_mismatches, 0, "{a:?}");
    assert!(a.resyncs > 0 && a.resyncs <= a.falls, "{a:?}");
    assert_eq!(
        a.fell_behind, a.resyncs,
        "and it is told once per resynchronizing keyframe"
    );
    assert!(
        a.applied > 2 * a.keyframes,
        "deltas apply between resyncs: {a:?}"
    );
    // The pixels: as close to the ray-traced truth as PSAO gets here.
    let posed = PosedScene::new(&scene, pipeline.time()).unwrap();
    let g = posed.gbuffer(&view());
    assert!(
        g.covered() > g.pixels() / 2,
        "{} pixels covered",
        g.covered()
    );
    let reference = ray_traced_ao(
        &posed.tracer(),
        &g,
        &AoParams {
            rays: REFERENCE_RAYS,
            ..pipeline.config().ao
        },
    )
    .unwrap();
    let e = rmse(&reference, &image).unwrap();
    eprintln!(
        "{a:?}; RMSE {e:.4} against the reference ({} pixels covered)",
        g.covered()
    );
    assert!(e < RMSE_BOUND, "RMSE {e:.4} against the bound {RMSE_BOUND}");
    // Deterministic: the same seed, the same run and the same pixels.
    let (b, image_b, _, _) = run(7);
    assert_eq!(a, b, "the same seed gives the same run");
    assert!(image == image_b, "and the same pixels");
}
