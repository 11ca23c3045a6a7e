//! A session recorded over loopback QUIC into a capture file
//! (spec/capture.md) replays into a mirror: the first frame is a keyframe,
//! every later one applies, and the replay is never ahead of the live
//! client.

use std::time::Duration;

use psao_proto::capture::{CaptureReader, CaptureWriter};
use psao_proto::*;
use psao_scene::Pipeline;
use psao_tests::scenes::{pipeline_config, sliding_box};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recorded_session_replays_into_a_mirror() {
    let scene = sliding_box();
    let pipeline = Pipeline::new(scene, pipeline_config(64.0, 64)).unwrap();
    let id = Identity::self_signed().unwrap();
    let server = serve(pipeline, ServerConfig::default(), &id).await.unwrap();
    let rec = connect(
        server.local_addr(),
        &Trust::Fingerprint(server.fingerprint()),
        ClientConfig {
            capture: true,
            ..ClientConfig::default()
        },
        Duration::from_secs(10),
    )
    .await
    .unwrap();
    let start = std::time::Instant::now();
    let mut w = CaptureWriter::new(Vec::new()).unwrap();
    let mut n = 0;
    while start.elapsed() < Duration::from_millis(600) {
        tokio::time::sleep(Duration::from_millis(50)).await;
        let (frames, dropped) = rec.take_captured();
        assert_eq!(dropped, 0);
        for (at, f) in frames {
            w.write(at.duration_since(start).as_micros() as u64, &f)
                .unwrap();
            n += 1;
        }
    }
    let file = w.finish().unwrap();
    assert!(n > 10, "{n} frames recorded");
    let mut decoder = psao_codec::Decoder::new(psao_codec::Limits::default());
    let mut first = true;
    for r in CaptureReader::new(&file[..], 1 << 26).unwrap() {
        let ev = decoder.receive(&r.unwrap().frame).unwrap();
        match ev {
            psao_codec::Event::Applied { keyframe, .. } => assert_eq!(keyframe, first),
            other => panic!("{other:?}"),
        }
        first = false;
    }
    // The replayed mirror is the recording client's mirror.
    let live = rec.with_session(|s| s.mirror().sequence());
    assert!(decoder.mirror().sequence() <= live);
    rec.close().await;
    server.shutdown(Duration::from_secs(1)).await.unwrap();
}
