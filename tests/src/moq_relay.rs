//! The real `moq-relay` as a process on loopback, for the MoQ tests: one
//! relay, or a second clustered with it, each with a certificate it
//! generates and the SHA-256 its HTTP endpoint serves.
//!
//! The binary is `$PSAO_MOQ_RELAY`, or `moq-relay` on the `PATH` (CI
//! installs the pinned version with `cargo install moq-relay --version
//! 0.17.10`). Where it is missing, [`MoqRelay::start`] returns `None` and
//! the tests say they skip, unless `PSAO_REQUIRE_RELAY` is set: then they
//! fail.
//!
//! The relays of a cluster share one certificate ([`RelayCert`]), so a
//! subscriber pins one fingerprint for all of them.

use std::io::{Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A certificate the relays of a test cluster share (each relay serves it;
/// a relay dialing another pins it).
pub struct RelayCert {
    /// PEM certificate file.
    pub cert: PathBuf,
    /// PEM key file.
    pub key: PathBuf,
    /// SHA-256 of the certificate.
    pub fingerprint: [u8; 32],
}

impl RelayCert {
    /// A fresh self-signed certificate for localhost and 127.0.0.1, in
    /// files under the temporary directory.
    pub fn generate() -> RelayCert {
        let (id, cert, key) =
            psao_proto::tls::Identity::self_signed_pem().expect("a self-signed certificate");
        let dir = std::env::temp_dir().join(
            format!("psao-moq-cert-{}-{:?}", std::process::id(), Instant::now())
                .replace([' ', ':', '{', '}', ','], "_"),
        );
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let (c, k) = (dir.join("cert.pem"), dir.join("key.pem"));
        std::fs::write(&c, cert).expect("writing the certificate");
        std::fs::write(&k, key).expect("writing the key");
        RelayCert {
            cert: c,
            key: k,
            fingerprint: id.fingerprint(),
        }
    }
}

/// A running relay, killed when dropped.
pub struct MoqRelay {
    child: Child,
    /// Its QUIC (UDP) and HTTP (TCP) port on 127.0.0.1.
    pub port: u16,
    /// SHA-256 of its certificate.
    pub fingerprint: [u8; 32],
    /// Its log file.
    pub log: PathBuf,
}

/// The relay binary, if there is one.
pub fn relay_binary() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("PSAO_MOQ_RELAY") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("moq-relay"))
        .find(|p| p.is_file())
}

/// Whether a missing relay fails the test instead of skipping it.
pub fn relay_required() -> bool {
    std::env::var_os("PSAO_REQUIRE_RELAY").is_some()
}

/// A port free for both UDP and TCP on 127.0.0.1 (as far as one can tell
/// without holding it).
fn free_port() -> u16 {
    for _ in 0..64 {
        let udp = UdpSocket::bind("127.0.0.1:0").expect("a UDP port");
        let port = udp.local_addr().unwrap().port();
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
    panic!("no port free for both UDP and TCP");
}

/// GET `path` from the relay's HTTP listener; the body.
fn http_get(port: u16, path: &str) -> std::io::Result<String> {
    let mut s = TcpStream::connect(("127.0.0.1", port))?;
    s.set_read_timeout(Some(Duration::from_secs(2)))?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    )?;
    let mut out = String::new();
    s.read_to_string(&mut out)?;
    Ok(out
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, b)| b.to_string()))
}

impl MoqRelay {
    /// Starts a relay serving `cert`, clustered with `peer` (it dials
    /// `peer`) if given, and waits until it serves its certificate's
    /// fingerprint. `None` when no
    /// binary is found and the relay is not required.
    ///
    /// # Panics
    /// When the relay does not come up within 20 s, or is required and
    /// missing.
    pub fn start(name: &str, cert: &RelayCert, peer: Option<&MoqRelay>) -> Option<MoqRelay> {
        let Some(bin) = relay_binary() else {
            assert!(
                !relay_required(),
                "PSAO_REQUIRE_RELAY is set and no moq-relay was found (set PSAO_MOQ_RELAY or put it on the PATH)"
            );
            eprintln!("skipped: no moq-relay (set PSAO_MOQ_RELAY or put it on the PATH)");
            return None;
        };
        let port = free_port();
        let log = std::env::temp_dir().join(format!(
            "psao-moq-relay-{name}-{}-{port}.log",
            std::process::id()
        ));
        let mut cmd = Command::new(&bin);
        cmd.arg("--listen")
            .arg(format!("127.0.0.1:{port}"))
            .arg("--listen-tls-cert")
            .arg(&cert.cert)
            .arg("--listen-tls-key")
            .arg(&cert.key)
            .arg("--web-http-listen")
            .arg(format!("127.0.0.1:{port}"))
            .arg("--auth-public")
            .arg("**");
        if let Some(p) = peer {
            cmd.arg("--cluster-connect")
                .arg(format!("https://127.0.0.1:{}/", p.port))
                .arg("--connect-tls-fingerprint")
                .arg(hex(&p.fingerprint));
        }
        let file = std::fs::File::create(&log).expect("the relay's log file");
        let child = cmd
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(file.try_clone().expect("a second handle"))
            .stderr(file)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {}: {e}", bin.display()));
        let mut relay = MoqRelay {
            child,
            port,
            fingerprint: [0; 32],
            log,
        };
        let until = Instant::now() + Duration::from_secs(20);
        loop {
            if let Ok(body) = http_get(port, "/certificate.sha256")
                && let Some(f) = parse_hex(body.trim())
            {
                relay.fingerprint = f;
                return Some(relay);
            }
            if let Ok(Some(status)) = relay.child.try_wait() {
                panic!(
                    "moq-relay exited ({status}) before serving; its log:\n{}",
                    std::fs::read_to_string(&relay.log).unwrap_or_default()
                );
            }
            assert!(
                Instant::now() < until,
                "moq-relay did not serve its fingerprint within 20 s; its log:\n{}",
                std::fs::read_to_string(&relay.log).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The relay's URL for `path`.
    pub fn url(&self, path: &str) -> String {
        format!("https://127.0.0.1:{}/{path}", self.port)
    }

    /// Kills the relay now.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Its log so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for MoqRelay {
    fn drop(&mut self) {
        self.kill();
        let _ = std::fs::remove_file(&self.log);
    }
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

fn parse_hex(s: &str) -> Option<[u8; 32]> {
    let s: String = s.chars().filter(|c| *c != ':').collect();
    if s.len() != 64 {
        return None;
    }
    let mut out = [0; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}
