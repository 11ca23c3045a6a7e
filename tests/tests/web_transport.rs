//! The WebTransport binding (spec/session.md 9) against the reference
//! server, with web-transport-quinn as the client (a browser's part is
//! tests/browser/, driven by psao-cli's browser test): a session mirrors
//! the server's tables with digests matched, beside a native client; a
//! page's bad input gets the close code a native client gets for the same
//! bytes; a second stream, a wrong path and a WebTransport session after
//! the certificate was replaced.

use std::time::Duration;

use psao_proto::control::{Control, Hello};
use psao_proto::tls::{client_config, client_crypto};
use psao_proto::web::WEB_PATH;
use psao_proto::*;
use psao_scene::{Pipeline, PipelineConfig};
use psao_tests::relay::{Impairment, Relay};
use psao_tests::scenes::{pipeline_config, sliding_box};
use web_transport_quinn as wt;

fn source() -> Pipeline {
    let config = PipelineConfig {
        ..pipeline_config(64.0, 8)
    };
    Pipeline::new(sliding_box(), config).expect("the pipeline builds")
}

/// A server with a WebTransport endpoint; its WebTransport certificate.
async fn server() -> (ServerHandle<Pipeline>, [u8; 32]) {
    let config = ServerConfig {
        idle_timeout: Duration::from_secs(5),
        digest_interval: 10,
        ..ServerConfig::default()
    };
    let mut server = serve(source(), config, &Identity::self_signed().unwrap())
        .await
        .unwrap();
    let web = Identity::self_signed().unwrap();
    server
        .listen_web("127.0.0.1:0".parse().unwrap(), &web)
        .unwrap();
    (server, web.fingerprint())
}

/// A WebTransport session to `path` on the server, pinning `fingerprint`.
async fn web_session(
    server: &ServerHandle<Pipeline>,
    fingerprint: [u8; 32],
    path: &str,
) -> Result<wt::Session, wt::ClientError> {
    let port = server.web_addr().expect("listening").port();
    web_session_at(port, fingerprint, path).await
}

/// A WebTransport session to `path` on `port` of the loopback address.
async fn web_session_at(
    port: u16,
    fingerprint: [u8; 32],
    path: &str,
) -> Result<wt::Session, wt::ClientError> {
    let crypto = client_crypto(&Trust::Fingerprint(fingerprint), &[wt::ALPN.as_bytes()]).unwrap();
    let endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let client = wt::Client::new(
        endpoint,
        quinn::ClientConfig::new(std::sync::Arc::new(crypto)),
    );
    let url: url::Url = format!("https://localhost:{port}{path}").parse().unwrap();
    client.connect(url).await
}

/// A [`ClientSession`] run over a WebTransport session.
struct WebClient {
    client: ClientSession,
    control: wt::SendStream,
    control_in: wt::RecvStream,
    frames: wt::RecvStream,
    asked: bool,
}

impl WebClient {
    /// Opens the control stream, sends `HELLO` and accepts the frame
    /// stream.
    async fn start(session: &wt::Session) -> WebClient {
        let mut client = ClientSession::new(ClientConfig::default());
        let (mut control, control_in) = session.open_bi().await.unwrap();
        control
            .write_all(&client.take_transmit().unwrap())
            .await
            .unwrap();
        let frames = session.accept_uni().await.expect("the frame stream");
        WebClient {
            client,
            control,
            control_in,
            frames,
            asked: false,
        }
    }

    /// Reads and applies what arrives until `done` holds (true) or the
    /// frame stream finishes (false); asks for a digest every 10 frames.
    async fn until(&mut self, done: impl Fn(&ClientSession) -> bool) -> bool {
        let (mut cbuf, mut fbuf) = (vec![0u8; 4096], vec![0u8; 65536]);
        let until = tokio::time::Instant::now() + Duration::from_secs(30);
        while !done(&self.client) {
            tokio::select! {
                r = self.control_in.read(&mut cbuf) => {
                    let n = r.unwrap().expect("the control stream stays open");
                    self.client.on_control(&cbuf[..n]).unwrap();
                }
                r = self.frames.read(&mut fbuf) => match r.unwrap() {
                    Some(n) => self.client.on_frames(&fbuf[..n]).unwrap(),
                    None => return false,
                },
                _ = tokio::time::sleep_until(until) => {
                    panic!("timed out: {:?}", self.client.stats())
                }
            }
            if !self.asked && self.client.welcome().is_some() {
                self.asked = self.client.request_digests(10);
            }
            while let Some(out) = self.client.take_transmit() {
                self.control.write_all(&out).await.unwrap();
            }
        }
        true
    }
}

/// Follows a session until `digests` digests matched (and none differed).
async fn follow(session: &wt::Session, digests: u64) -> WebClient {
    let mut c = WebClient::start(session).await;
    assert!(c.until(|s| s.stats().digests_matched >= digests).await);
    assert_eq!(c.client.stats().digest_mismatches, 0);
    c
}

/// The close code and reason a WebTransport session ends with.
async fn web_close(session: &wt::Session) -> (CloseCode, String) {
    match tokio::time::timeout(Duration::from_secs(10), session.closed()).await {
        Ok(wt::SessionError::WebTransportError(wt::WebTransportError::Closed(code, reason))) => {
            (CloseCode::from_code(code as u64), reason)
        }
        other => panic!("not closed by the server: {other:?}"),
    }
}

/// The close code a native client gets for `bytes` written after its
/// `HELLO` was answered.
async fn native_close(server: &ServerHandle<Pipeline>, bytes: &[u8]) -> CloseCode {
    let mut ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    ep.set_default_client_config(client_config(&Trust::Fingerprint(server.fingerprint())).unwrap());
    let conn = ep
        .connect(server.local_addr(), "localhost")
        .unwrap()
        .await
        .unwrap();
    let (mut send, mut recv) = conn.open_bi().await.unwrap();
    send.write_all(&hello()).await.unwrap();
    let mut len = [0u8; 2];
    recv.read_exact(&mut len).await.unwrap();
    send.write_all(bytes).await.unwrap();
    match tokio::time::timeout(Duration::from_secs(10), conn.closed()).await {
        Ok(quinn::ConnectionError::ApplicationClosed(c)) => {
            CloseCode::from_code(c.error_code.into_inner())
        }
        other => panic!("not closed by the server: {other:?}"),
    }
}

fn hello() -> Vec<u8> {
    Control::Hello(Hello {
        version: 1,
        compressions: 0b111,
        point_formats: 0b11,
        max_frame_bytes: 1 << 24,
        max_payload_bytes: 1 << 24,
        max_mirror_bytes: 1 << 30,
        viewer: false,
        overflow: true,
        digest: false,
    })
    .to_bytes()
    .to_vec()
}

/// A WebTransport session that has sent `HELLO` and read `WELCOME`'s
/// length, then writes `bytes` on its control stream.
async fn web_sends(server: &ServerHandle<Pipeline>, fp: [u8; 32], bytes: &[u8]) -> wt::Session {
    let session = web_session(server, fp, WEB_PATH).await.unwrap();
    let (mut send, mut recv) = session.open_bi().await.unwrap();
    send.write_all(&hello()).await.unwrap();
    let mut len = [0u8; 2];
    recv.read_exact(&mut len).await.unwrap();
    send.write_all(bytes).await.unwrap();
    // The halves stay alive until the close (dropping them would finish
    // or stop the control stream: a violation of its own).
    std::mem::forget((send, recv));
    session
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_web_transport_session_mirrors_the_server_with_digests_matched() {
    let (server, fp) = server().await;
    let session = web_session(&server, fp, WEB_PATH).await.unwrap();
    let mut web = follow(&session, 3).await;
    // A native client beside it.
    let native = connect(
        server.local_addr(),
        &Trust::Fingerprint(server.fingerprint()),
        ClientConfig::default(),
        Duration::from_secs(10),
    )
    .await
    .unwrap();
    assert!(
        native
            .wait_for(Duration::from_secs(10), |s| s.stats().applied >= 5)
            .await
    );
    // Stopped, the server flushes and finishes the frame streams: both
    // mirrors end equal to its tables.
    let stop = tokio::spawn(server.shutdown(Duration::from_secs(3)));
    assert!(!web.until(|_| false).await, "the frame stream finishes");
    let (pipeline, stats) = stop.await.unwrap().unwrap();
    assert_eq!(stats.accepted, 2);
    assert_eq!(web.client.mirror().sequence(), Some(stats.sequence));
    assert!(
        native
            .wait_for(Duration::from_secs(5), |s| s.mirror().sequence()
                == Some(stats.sequence))
            .await
    );
    let tables_equal = |m: &psao_codec::Mirror| {
        (0..pipeline.instance_count()).all(|i| {
            let t = pipeline.table(i).unwrap();
            m.instance(i as u32)
                .is_some_and(|m| m.words() == t.words() && m.buckets() == t.buckets())
        })
    };
    assert!(
        tables_equal(web.client.mirror()),
        "{:?}",
        web.client.stats()
    );
    assert!(native.with_session(|s| tables_equal(s.mirror())));
    // Closed with the capsule's server_shutdown (spec/session.md 9.3).
    let (code, reason) = web_close(&session).await;
    assert_eq!(code, CloseCode::ServerShutdown, "{reason}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_over_web_transport_gets_the_native_close_codes() {
    let (server, fp) = server().await;
    let cases: [(&str, Vec<u8>, CloseCode); 3] = [
        (
            "an unknown type",
            vec![1, 0, 0x7f],
            CloseCode::ProtocolViolation,
        ),
        (
            "a length above 1024",
            vec![0x01, 0x04, 0x11],
            CloseCode::MessageTooLarge,
        ),
        ("a second HELLO", hello(), CloseCode::ProtocolViolation),
    ];
    for (what, bytes, expected) in cases {
        let native = native_close(&server, &bytes).await;
        let session = web_sends(&server, fp, &bytes).await;
        let (web, reason) = web_close(&session).await;
        assert_eq!(native, expected, "{what}: native");
        assert_eq!(web, native, "{what}: {reason}");
    }
    // A second bidirectional stream in the session.
    let session = web_sends(&server, fp, &[]).await;
    let extra = session.open_bi().await.unwrap();
    std::mem::forget(extra);
    let (code, reason) = web_close(&session).await;
    assert_eq!(code, CloseCode::ProtocolViolation, "{reason}");
    // A unidirectional stream from the client.
    let session = web_sends(&server, fp, &[]).await;
    let mut uni = session.open_uni().await.unwrap();
    uni.write_all(b"x").await.unwrap();
    std::mem::forget(uni);
    let (code, reason) = web_close(&session).await;
    assert_eq!(code, CloseCode::ProtocolViolation, "{reason}");
}

/// A violation's close capsule reaches the client even when the server's
/// datagrams are lost for a while after it (a loaded browser that reads
/// its socket late loses them so): the server sends the capsule again and
/// closes the connection only after it had time to arrive. A connection
/// closed first tells a browser no code (patches/README.md).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_close_capsule_lost_for_a_moment_is_sent_again() {
    let (server, fp) = server().await;
    let relay = Relay::start(server.web_addr().expect("listening"), Impairment::default())
        .await
        .unwrap();
    let session = web_session_at(relay.addr().port(), fp, WEB_PATH)
        .await
        .unwrap();
    let (mut send, mut recv) = session.open_bi().await.unwrap();
    send.write_all(&hello()).await.unwrap();
    let mut len = [0u8; 2];
    recv.read_exact(&mut len).await.unwrap();
    // The capsule and the server's first retransmissions of it are lost.
    relay.cut_downstream(true);
    send.write_all(&[0x01, 0x04, 0x11]).await.unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    relay.cut_downstream(false);
    let (code, reason) = web_close(&session).await;
    assert_eq!(code, CloseCode::MessageTooLarge, "{reason}");
    assert!(relay.dropped() > 0, "the relay dropped nothing");
    std::mem::forget((send, recv));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn another_path_is_refused_and_a_new_certificate_serves_new_sessions() {
    let (server, fp) = server().await;
    for path in ["/other", "/psao?x=1"] {
        match web_session(&server, fp, path).await {
            Err(e) => assert!(e.to_string().contains("404"), "{path}: {e}"),
            Ok(_) => panic!("a session on {path}"),
        }
    }
    let old = web_session(&server, fp, WEB_PATH).await.unwrap();
    let next = Identity::self_signed().unwrap();
    server.set_web_identity(&next).unwrap();
    // The old certificate no longer serves new sessions; the new one does,
    // and the session opened before goes on.
    assert!(web_session(&server, fp, WEB_PATH).await.is_err());
    let new = web_session(&server, next.fingerprint(), WEB_PATH)
        .await
        .unwrap();
    follow(&new, 1).await;
    follow(&old, 1).await;
    drop(server);
}

/// The `wt` examples of spec/session.md 9.5, and section 8's `HELLO`.
fn spec_examples() -> Vec<(String, Vec<u8>)> {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../spec/session.md"))
        .unwrap();
    let mut out = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let Some(name) = line
            .strip_prefix("```wt ")
            .or_else(|| line.strip_prefix("```hex ").filter(|n| *n == "HELLO"))
        else {
            continue;
        };
        let bytes = lines
            .by_ref()
            .take_while(|l| !l.starts_with("```"))
            .flat_map(|l| l.split_whitespace())
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect();
        out.push((name.to_string(), bytes));
    }
    out
}

#[test]
fn the_web_transport_examples_match_the_library() {
    use bytes::BufMut;
    use wt::proto::{Capsule, Frame, StreamUni, VarInt, error_to_http3};
    let examples = spec_examples();
    let get = |name: &str| {
        examples
            .iter()
            .find(|e| e.0 == name)
            .unwrap_or_else(|| panic!("example {name}"))
            .1
            .clone()
    };
    let mut control = Vec::new();
    Frame::WEBTRANSPORT.encode(&mut control);
    VarInt::from_u32(0).encode(&mut control);
    control.extend_from_slice(&get("HELLO"));
    assert_eq!(control, get("CONTROL-STREAM"));
    let mut frames = Vec::new();
    StreamUni::WEBTRANSPORT.encode(&mut frames);
    VarInt::from_u32(0).encode(&mut frames);
    frames.put_u32_le(40);
    assert_eq!(frames, get("FRAME-STREAM"));
    let mut close = Vec::new();
    Capsule::CloseWebTransportSession {
        code: CloseCode::ProtocolViolation.code(),
        reason: "unknown type".into(),
    }
    .encode(&mut close);
    assert_eq!(close, get("CLOSE-PROTOCOL-VIOLATION"));
    let mut shutdown = Vec::new();
    VarInt::from_u64(error_to_http3(CloseCode::ServerShutdown.code()))
        .unwrap()
        .encode(&mut shutdown);
    assert_eq!(shutdown, get("SERVER-SHUTDOWN-HTTP3"));
    assert_eq!(examples.len(), 5, "the four examples of 9.5 and HELLO");
}
