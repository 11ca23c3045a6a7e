//! The page's HTTPS server and certificates: every path of the site with
//! its content type, 404 and 405, a certificate a browser accepts by its
//! hash (P-256, under 14 days), and a replaced certificate serving new
//! connections and named by the config.

use std::sync::Arc;
use std::time::Duration;

use psao_proto::Trust;
use psao_proto::tls::client_tls;
use psao_web::cert::{CertError, MAX_VALIDITY};
use psao_web::{HttpsServer, PageConfig, Rotation, Site, WebCertificate};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

fn page() -> PageConfig {
    PageConfig {
        url: "https://127.0.0.1:4443/psao".into(),
        scene: "default".into(),
        frame_rate: 60,
        camera: ([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], 0.9),
    }
}

/// A site whose wasm module is two small files in a temporary folder.
fn site(fingerprint: &str) -> Arc<Site> {
    let dir = std::env::temp_dir().join(format!("psao-web-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("psao_wasm.js"), b"export default 1;").unwrap();
    std::fs::write(dir.join("psao_wasm_bg.wasm"), b"\0asm\x01\0\0\0").unwrap();
    Site::new(&dir, b"glTF-bytes".to_vec(), page(), fingerprint).unwrap()
}

/// One request over a new TLS connection pinning `fingerprint`: (status
/// line, headers, body).
async fn request(
    server: &HttpsServer,
    fingerprint: [u8; 32],
    head: &str,
) -> std::io::Result<(String, String, Vec<u8>)> {
    let tls = client_tls(&Trust::Fingerprint(fingerprint), &[b"http/1.1"]).unwrap();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(tls));
    let tcp = tokio::net::TcpStream::connect(server.local_addr()).await?;
    let name = rustls::pki_types::ServerName::try_from("localhost").unwrap();
    let mut s = connector.connect(name, tcp).await?;
    s.write_all(format!("{head}\r\nHost: localhost\r\nConnection: close\r\n\r\n").as_bytes())
        .await?;
    let mut all = Vec::new();
    let _ = s.read_to_end(&mut all).await;
    let split = all
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a response head");
    let text = String::from_utf8_lossy(&all[..split]).to_string();
    let (status, headers) = text.split_once("\r\n").unwrap_or((&text, ""));
    Ok((
        status.to_string(),
        headers.to_lowercase(),
        all[split + 4..].to_vec(),
    ))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_path_with_its_type_and_nothing_else() {
    let cert = WebCertificate::generate(Duration::from_secs(3600)).unwrap();
    let site = site(&cert.fingerprint_hex());
    let server = HttpsServer::start("127.0.0.1:0".parse().unwrap(), &cert.identity, site.clone())
        .await
        .unwrap();
    let fp = cert.fingerprint;
    for (path, kind) in [
        ("/", "text/html"),
        ("/index.html", "text/html"),
        ("/pkg/psao_wasm.js", "text/javascript"),
        ("/pkg/psao_wasm_bg.wasm", "application/wasm"),
        ("/reconstruct.wgsl", "text/plain"),
        ("/scene.glb", "model/gltf-binary"),
        ("/config.json", "application/json"),
    ] {
        let (status, headers, body) = request(&server, fp, &format!("GET {path} HTTP/1.1"))
            .await
            .unwrap();
        assert!(status.contains("200"), "{path}: {status}");
        assert!(
            headers.contains(&format!("content-type: {kind}")),
            "{path}: {headers}"
        );
        assert_eq!(
            Some(body.len()),
            site.get(path).map(|f| f.1.len()),
            "{path}"
        );
    }
    let (_, _, body) = request(&server, fp, "GET /config.json HTTP/1.1")
        .await
        .unwrap();
    let config: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(config["certificate_hashes"][0], cert.fingerprint_hex());
    assert_eq!(config["url"], "https://127.0.0.1:4443/psao");
    assert_eq!(config["frame_rate"], 60);
    let (status, _, body) = request(&server, fp, "GET /../etc/passwd HTTP/1.1")
        .await
        .unwrap();
    assert!(status.contains("404") || status.contains("400"), "{status}");
    assert!(!String::from_utf8_lossy(&body).contains("root:"));
    let (status, _, _) = request(&server, fp, "GET /nothing-here HTTP/1.1")
        .await
        .unwrap();
    assert!(status.contains("404"), "{status}");
    let (status, headers, _) = request(&server, fp, "POST / HTTP/1.1").await.unwrap();
    assert!(status.contains("405"), "{status}");
    assert!(headers.contains("allow: get, head"), "{headers}");
    let (status, headers, body) = request(&server, fp, "HEAD /scene.glb HTTP/1.1")
        .await
        .unwrap();
    assert!(
        status.contains("200") && headers.contains("content-length: 10"),
        "{headers}"
    );
    assert!(body.is_empty());
    // Too many headers, or too many bytes of them: refused, not buffered.
    let many: String = (0..40).map(|k| format!("\r\nX-{k}: v")).collect();
    let (status, _, _) = request(&server, fp, &format!("GET / HTTP/1.1{many}"))
        .await
        .unwrap();
    assert!(status.contains("431"), "{status}");
    let long = format!("GET / HTTP/1.1\r\nX-Long: {}", "a".repeat(20_000));
    let refused = request(&server, fp, &long).await;
    assert!(
        refused
            .as_ref()
            .map_or(true, |r| r.0.contains("431") || r.0.contains("400")),
        "{:?}",
        refused.map(|r| r.0)
    );
    // A client pinning another certificate is refused by its own check.
    assert!(request(&server, [7; 32], "GET / HTTP/1.1").await.is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replaced_certificate_serves_new_connections_and_the_config_names_it() {
    let old = WebCertificate::generate(Duration::from_secs(3600)).unwrap();
    let site = site(&old.fingerprint_hex());
    let server = HttpsServer::start("127.0.0.1:0".parse().unwrap(), &old.identity, site.clone())
        .await
        .unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let rotation = Rotation {
        valid_for: Duration::from_secs(3600),
        replace_after: Duration::from_millis(300),
    };
    rotation.check().unwrap();
    let task = rotation
        .spawn(&old, move |c| {
            let _ = tx.send(c);
        })
        .unwrap();
    let new = tokio::time::timeout(Duration::from_secs(10), rx.recv())
        .await
        .unwrap()
        .unwrap();
    task.abort();
    assert_ne!(new.fingerprint, old.fingerprint);
    // The same key: Chromium's SPKI pin stays good.
    assert_eq!(new.spki_sha256, old.spki_sha256);
    server.set_identity(&new.identity).unwrap();
    site.set_fingerprint(&new.fingerprint_hex());
    assert!(
        request(&server, old.fingerprint, "GET / HTTP/1.1")
            .await
            .is_err()
    );
    let (status, _, body) = request(&server, new.fingerprint, "GET /config.json HTTP/1.1")
        .await
        .unwrap();
    assert!(status.contains("200"));
    let config: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(config["certificate_hashes"][0], new.fingerprint_hex());
}

#[test]
fn certificates_are_what_a_browser_pins() {
    let c = WebCertificate::generate(Duration::from_secs(10 * 24 * 3600)).unwrap();
    let der = c.identity.chain[0].as_ref();
    // The prime256v1 curve's OID (1.2.840.10045.3.1.7) and
    // ecdsa-with-SHA256's (1.2.840.10045.4.3.2).
    let has = |oid: &[u8]| der.windows(oid.len()).any(|w| w == oid);
    assert!(has(&[
        0x06, 0x08, 0x2a, 0x86, 0x48, 0xce, 0x3d, 0x03, 0x01, 0x07
    ]));
    assert!(has(&[
        0x06, 0x08, 0x2a, 0x86, 0x48, 0xce, 0x3d, 0x04, 0x03, 0x02
    ]));
    let left = c
        .not_after
        .duration_since(std::time::SystemTime::now())
        .unwrap();
    assert!(left < MAX_VALIDITY && left > Duration::from_secs(9 * 24 * 3600));
    assert_eq!(c.fingerprint_hex().len(), 64);
    assert_eq!(c.spki_sha256.len(), 44, "base64 of 32 bytes");
    assert!(matches!(
        WebCertificate::generate(Duration::from_secs(15 * 24 * 3600)),
        Err(CertError::Validity(_))
    ));
    assert!(Rotation::default().check().is_ok());
    let late = Rotation {
        valid_for: Duration::from_secs(3600),
        replace_after: Duration::from_secs(3600),
    };
    assert!(late.check().is_err());
}
