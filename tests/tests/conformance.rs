//! The conformance kit (psao-conformance) against psao's own server, where
//! every case must pass, and against a deliberately broken double (a
//! server that answers the handshake and one keyframe, then closes every
//! violation with the wrong code and answers no request), where each
//! case that checks a close code or an answer must fail: proof that the
//! cases can fail.

use std::time::Duration;

use psao_conformance::probe::Target;
use psao_conformance::{Outcome, server_cases};
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
