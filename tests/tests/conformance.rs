//! The conformance kit (psao-conformance) against psao's own server, where
//! every case must pass, and against a deliberately broken double (a
//! server that answers the handshake and one keyframe, then closes every
//! violation with the wrong code and answers no request), where each
//! case that checks a close code or an answer must fail: proof that the
//! cases can fail.

use std::time::Duration;

use psao_conformance::probe::Target;
use psao_conformance::{Outcome, client_cases, server_cases};
use psao_proto::control::{Control, ControlReader, Sender, Welcome};
use psao_proto::tls::server_config;
use psao_proto::{CloseCode, Identity, ServerConfig, Trust, serve};
use psao_scene::Pipeline;
use psao_tests::raw;
use psao_tests::scenes::{pipeline_config, sliding_box};

fn target(addr: std::net::SocketAddr, fingerprint: [u8; 32]) -> Target {
    Target {
        addr,
        trust: Trust::Fingerprint(fingerprint),
        server_name: "localhost".into(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn psao_serve_passes_every_case() {
    let id = Identity::self_signed().unwrap();
    // Without overflow chains, so that the spec's example HELLO (which
    // does not offer them) is served too.
    let mut config = pipeline_config(64.0, 8);
    config.layout.overflow = false;
    let pipeline = Pipeline::new(sliding_box(), config).unwrap();
    let server = serve(pipeline, ServerConfig::default(), &id).await.unwrap();
    let report = server_cases::run(&target(server.local_addr(), server.fingerprint()), "").await;
    let lines: Vec<String> = report.cases.iter().map(|c| c.line()).collect();
    assert!(report.ok(), "{}\n{}", lines.join("\n"), report.summary());
    let (passed, _, skipped) = report.counts();
    assert_eq!(skipped, 0, "{}", lines.join("\n"));
    assert_eq!(passed, server_cases::cases().len());
}

/// The broken double: WELCOME and one keyframe for a good HELLO, then
/// `internal_error` for anything at all, and for a bad HELLO.
async fn broken_server(id: &Identity) -> (quinn::Endpoint, std::net::SocketAddr) {
    let config = server_config(id, Duration::from_secs(10)).unwrap();
    let ep = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = ep.local_addr().unwrap();
    let accept = ep.clone();
    tokio::spawn(async move {
        while let Some(incoming) = accept.accept().await {
            tokio::spawn(async move {
                let Ok(conn) = incoming.await else { return };
                let Ok((mut send, mut recv)) = conn.accept_bi().await else {
                    return;
                };
                let wrong = |conn: &quinn::Connection| {
                    conn.close(CloseCode::InternalError.code().into(), b"broken double")
                };
                let mut reader = ControlReader::from(Sender::Client);
                let mut buf = [0u8; 4096];
                let mut welcomed = false;
                let mut frames_stream = None;
                loop {
                    let n = match tokio::time::timeout(Duration::from_secs(6), recv.read(&mut buf))
                        .await
                    {
                        Ok(Ok(Some(n))) => n,
                        _ => return wrong(&conn),
                    };
                    let mut input = &buf[..n];
                    match reader.read(&mut input) {
                        Ok(Some(Control::Hello(_))) if !welcomed => {
                            welcomed = true;
                            let w = Welcome {
                                version: 1,
                                compression: 0,
                                point_format: 0,
                                max_frame_bytes: 65_536,
                                max_payload_bytes: 65_536,
                                frame_rate: 60,
                                culling: false,
                                overflow: false,
                                digest: false,
                                scene: "broken".into(),
                            };
                            let _ = send.write_all(&Control::Welcome(w).to_bytes()).await;
                            let Ok(mut frames) = conn.open_uni().await else {
                                return;
                            };
                            let kf = raw::frame(
                                true,
                                1,
                                1,
                                &[raw::define(1, &raw::DEF), raw::transform(1, 1, 0.0)],
                            );
                            let _ = frames.write_all(&(kf.len() as u32).to_le_bytes()).await;
                            let _ = frames.write_all(&kf).await;
                            frames_stream = Some(frames);
                            if !input.is_empty() {
                                return wrong(&conn);
                            }
                        }
                        Ok(None) => {}
                        _ => return wrong(&conn),
                    }
                    let _ = &frames_stream;
                }
            });
        }
    });
    (ep, addr)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broken_server_fails_the_cases_it_breaks() {
    let id = Identity::self_signed().unwrap();
    let (_ep, addr) = broken_server(&id).await;
    let fingerprint = psao_proto::tls::fingerprint(&id.chain[0]);
    let report = server_cases::run(&target(addr, fingerprint), "").await;
    let lines: Vec<String> = report.cases.iter().map(|c| c.line()).collect();
    let all = lines.join("\n");
    let outcome = |id: &str| {
        &report
            .case(id)
            .unwrap_or_else(|| panic!("case {id}"))
            .outcome
    };
    // What it does right passes.
    assert_eq!(*outcome("hello.example"), Outcome::Passed, "{all}");
    assert_eq!(*outcome("hello.minimum-limits"), Outcome::Passed, "{all}");
    assert_eq!(*outcome("hello.example-limits"), Outcome::Passed, "{all}");
    // It offers no digests: skipped, not failed.
    assert!(
        matches!(outcome("digest.on-request"), Outcome::Skipped(_)),
        "{all}"
    );
    // Every case that checks a close code, an answer or going on fails.
    for c in &report.cases {
        if ![
            "hello.example",
            "hello.example-limits",
            "hello.minimum-limits",
            "digest.on-request",
        ]
        .contains(&c.id)
        {
            assert!(
                matches!(c.outcome, Outcome::Failed(_)),
                "{} should fail:\n{all}",
                c.id
            );
        }
    }
    assert!(!report.ok());
    let (_, failed, _) = report.counts();
    assert!(
        report
            .summary()
            .starts_with(&format!("3 passed, {failed} failed, 1 skipped")),
        "{}",
        report.summary()
    );
    // The outputs CI reads.
    assert!(
        report
            .to_junit("psao")
            .contains(&format!("failures=\"{failed}\""))
    );
    assert!(report.to_json().contains("\"outcome\": \"failed\""));
}

/// The kit's server mode: an endpoint whose first client is the one under
/// test.
fn harness(id: &Identity) -> quinn::Endpoint {
    let config = server_config(id, Duration::from_secs(10)).unwrap();
    quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn psao_client_passes_every_server_mode_case() {
    let id = Identity::self_signed().unwrap();
    let ep = harness(&id);
    let addr = ep.local_addr().unwrap();
    let fingerprint = psao_proto::tls::fingerprint(&id.chain[0]);
    let run = tokio::spawn(async move { client_cases::run(&ep, Duration::from_secs(20)).await });
    let client = psao_proto::connect(
        addr,
        &Trust::Fingerprint(fingerprint),
        psao_proto::ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await
    .unwrap();
    let report = run.await.unwrap();
    let all: Vec<String> = report.cases.iter().map(|c| c.line()).collect();
    assert!(report.ok(), "{}\n{}", all.join("\n"), report.summary());
    assert_eq!(report.counts(), (9, 0, 0), "{}", all.join("\n"));
    drop(client);
}

/// A broken client double: it sends HELLO, acknowledges every keyframe,
/// and never asks for one.
async fn never_asks(addr: std::net::SocketAddr, fingerprint: [u8; 32]) {
    let mut ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let mut cc = psao_proto::tls::client_config(&Trust::Fingerprint(fingerprint)).unwrap();
    let mut transport = quinn::TransportConfig::default();
    transport.max_concurrent_uni_streams(1u32.into());
    cc.transport_config(std::sync::Arc::new(transport));
    ep.set_default_client_config(cc);
    let conn = ep.connect(addr, "localhost").unwrap().await.unwrap();
    let (mut send, _recv) = conn.open_bi().await.unwrap();
    let hello = psao_proto::control::Hello {
        viewer: false,
        digest: true,
        ..psao_conformance::probe::example_hello()
    };
    send.write_all(&Control::Hello(hello).to_bytes())
        .await
        .unwrap();
    let Ok(mut frames) = conn.accept_uni().await else {
        return;
    };
    loop {
        let mut len = [0u8; 4];
        if frames.read_exact(&mut len).await.is_err() {
            break;
        }
        let mut f = vec![0u8; u32::from_le_bytes(len) as usize];
        if frames.read_exact(&mut f).await.is_err() {
            break;
        }
        if let Ok(h) = psao_codec::wire::FrameHeader::parse(&f)
            && h.keyframe
        {
            let _ = send.write_all(&Control::Ack(h.sequence).to_bytes()).await;
        }
    }
    conn.closed().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_asks_for_a_keyframe_fails_those_cases() {
    let id = Identity::self_signed().unwrap();
    let ep = harness(&id);
    let addr = ep.local_addr().unwrap();
    let fingerprint = psao_proto::tls::fingerprint(&id.chain[0]);
    let run = tokio::spawn(async move { client_cases::run(&ep, Duration::from_secs(20)).await });
    let double = tokio::spawn(never_asks(addr, fingerprint));
    let report = run.await.unwrap();
    let all = report
        .cases
        .iter()
        .map(|c| c.line())
        .collect::<Vec<_>>()
        .join("\n");
    for id in ["client.gap", "client.corrupt", "client.digest-mismatch"] {
        assert!(
            matches!(report.case(id).unwrap().outcome, Outcome::Failed(_)),
            "{id}:\n{all}"
        );
    }
    for id in [
        "client.hello",
        "client.join",
        "client.resync",
        "client.notices",
        "client.shutdown",
    ] {
        assert_eq!(
            report.case(id).unwrap().outcome,
            Outcome::Passed,
            "{id}:\n{all}"
        );
    }
    assert_eq!(report.summary(), "6 passed, 3 failed, 0 skipped");
    let _ = double.await;
}

/// A violation that arrives while the keyframe fills the server's
/// congestion window still gets its own close code. quinn-proto 0.11.19
/// held the CONNECTION_CLOSE back behind the full window, which a closed
/// connection never empties, so the client heard nothing and got a
/// stateless reset after the drain (patches/README.md): this fails
/// without the patch.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_violation_while_the_keyframe_fills_the_window_gets_its_close_code() {
    use psao_conformance::probe::{Probe, open_hello};
    let id = Identity::self_signed().unwrap();
    // A keyframe of tens of kB: more than a new connection's window.
    let pipeline = Pipeline::new(psao_scene::default_scene(), pipeline_config(64.0, 4)).unwrap();
    let server = serve(pipeline, ServerConfig::default(), &id).await.unwrap();
    let t = target(server.local_addr(), server.fingerprint());
    // An undefined message type (session.md 3): protocol_violation.
    let violation = [5, 0, 0x7f, 0, 0, 0, 0];
    let mut failed = Vec::new();
    for k in 0..64u64 {
        let mut p = Probe::connect(&t).await.unwrap();
        p.hello(open_hello()).await.unwrap();
        // The server sends the keyframe at its next tick after WELCOME
        // (60 Hz): over 64 connections the violation comes twice at each
        // millisecond of two ticks, so some find the keyframe in flight.
        tokio::time::sleep(Duration::from_millis(k % 32)).await;
        p.write(&violation).await.unwrap();
        if let Err(e) = p
            .expect_close(CloseCode::ProtocolViolation, Duration::from_secs(5))
            .await
        {
            failed.push(format!("connection {k}: {e}"));
        }
    }
    assert!(failed.is_empty(), "{}", failed.join("\n"));
}
