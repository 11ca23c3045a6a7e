//! `moq-relay` processes on loopback, for demos, benchmarks and tests: a
//! relay, or a cluster of them (each dials the one before), serving one
//! certificate they share so that a subscriber pins one fingerprint for
//! all of them. The binary is the real `moq-relay` (`cargo install
//! moq-relay --version 0.17.10`), found by [`find_relay_binary`].

use std::io::{Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use psao_proto::tls::{Identity, fingerprint_hex};

/// Why a local relay did not start.
#[derive(Debug, thiserror::Error)]
pub enum LocalRelayError {
    /// No binary was found.
    #[error(
        "no moq-relay found (set PSAO_MOQ_RELAY or put it on the PATH; install it with \
         `cargo install moq-relay --version 0.17.10 --no-default-features --features noq`)"
    )]
    NoBinary,
    /// A file could not be written or read.
    #[error("{path}: {why}")]
    File {
        /// The file.
        path: PathBuf,
        /// What failed.
        why: String,
    },
    /// The process did not start, or ended, or did not come up in time.
    #[error("moq-relay {what}; its log ({log}):\n{tail}")]
    Process {
        /// What happened.
        what: String,
        /// Its log file.
        log: PathBuf,
        /// The log's last lines.
        tail: String,
    },
}

/// The relay binary: `$PSAO_MOQ_RELAY`, or `moq-relay` on the `PATH`.
pub fn find_relay_binary() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("PSAO_MOQ_RELAY") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join("moq-relay"))
        .find(|p| p.is_file())
}

/// A certificate (and key) the relays of a cluster share.
#[derive(Clone, Debug)]
pub struct RelayCert {
    /// PEM certificate file.
    pub cert: PathBuf,
    /// PEM key file.
    pub key: PathBuf,
    /// SHA-256 of the certificate.
    pub fingerprint: [u8; 32],
}

impl RelayCert {
    /// A fresh self-signed certificate for localhost and 127.0.0.1,
    /// written to `dir/cert/` (created if missing). The directory holds
    /// nothing else: moq-relay watches the directory of its certificate
    /// and reloads it at every change there (a log file written beside it
    /// would have it reload in a loop).
    pub fn generate(dir: &Path) -> Result<RelayCert, LocalRelayError> {
        let dir = &dir.join("cert");
        let file_err = |path: &Path, e: &dyn std::fmt::Display| LocalRelayError::File {
            path: path.to_path_buf(),
            why: e.to_string(),
        };
        std::fs::create_dir_all(dir).map_err(|e| file_err(dir, &e))?;
        let (id, cert, key) = Identity::self_signed_pem().map_err(|e| file_err(dir, &e))?;
        let (c, k) = (dir.join("relay-cert.pem"), dir.join("relay-key.pem"));
        std::fs::write(&c, cert).map_err(|e| file_err(&c, &e))?;
        std::fs::write(&k, key).map_err(|e| file_err(&k, &e))?;
        Ok(RelayCert {
            cert: c,
            key: k,
            fingerprint: id.fingerprint(),
        })
    }
}

/// A running relay on 127.0.0.1, killed when dropped.
#[derive(Debug)]
pub struct LocalRelay {
    child: Child,
    /// Its QUIC (UDP) and HTTP (TCP) port on 127.0.0.1.
    pub port: u16,
    /// SHA-256 of the certificate it serves.
    pub fingerprint: [u8; 32],
    /// Its log file.
    pub log: PathBuf,
}

/// A port free for both UDP and TCP on 127.0.0.1 (as far as one can tell
/// without holding it).
fn free_port() -> std::io::Result<u16> {
    for _ in 0..64 {
        let udp = UdpSocket::bind("127.0.0.1:0")?;
        let port = udp.local_addr()?.port();
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return Ok(port);
        }
    }
    Err(std::io::Error::other("no port free for both UDP and TCP"))
}

/// How many ports [`LocalRelay::start`] tries.
pub const PORT_TRIES: u32 = 5;

/// How one try of [`LocalRelay::start`] failed.
enum Attempt {
    /// The relay found its port taken: worth trying another.
    PortTaken(LocalRelayError),
    /// Anything else.
    Failed(LocalRelayError),
}

impl From<LocalRelayError> for Attempt {
    fn from(e: LocalRelayError) -> Attempt {
        Attempt::Failed(e)
    }
}

/// GET `path` from a relay's HTTP listener; the body.
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
        .map_or(String::new(), |(_, b)| b.trim().to_string()))
}

fn tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(20)..].join("\n")
}

impl LocalRelay {
    /// Starts `bin` on a free port of 127.0.0.1 serving `cert`, open to
    /// anonymous publishers and subscribers, clustered with `peer` (it
    /// dials `peer`, pinning its certificate) if given, logging to `log`;
    /// returns once it serves its certificate's fingerprint (20 s at
    /// most per try).
    ///
    /// A port found free can be taken before the relay binds it (by any
    /// other socket on the machine, such as another test's outgoing
    /// connection); when the relay exits saying its address is in use, it
    /// is started again on another port, [`PORT_TRIES`] times in all.
    pub fn start(
        bin: &Path,
        cert: &RelayCert,
        peer: Option<&LocalRelay>,
        log: PathBuf,
    ) -> Result<LocalRelay, LocalRelayError> {
        let mut tries = 1;
        loop {
            let port = free_port().map_err(|e| LocalRelayError::Process {
                what: format!("has no port: {e}"),
                log: log.clone(),
                tail: String::new(),
            })?;
            match Self::start_once(bin, cert, peer, log.clone(), port) {
                Err(Attempt::PortTaken(_)) if tries < PORT_TRIES => tries += 1,
                Err(Attempt::PortTaken(LocalRelayError::Process { what, log, tail })) => {
                    return Err(LocalRelayError::Process {
                        what: format!("{what} (its port was taken on each of {PORT_TRIES} tries)"),
                        log,
                        tail,
                    });
                }
                Err(Attempt::PortTaken(e) | Attempt::Failed(e)) => return Err(e),
                Ok(relay) => return Ok(relay),
            }
        }
    }

    /// One try of [`LocalRelay::start`], on `port`.
    fn start_once(
        bin: &Path,
        cert: &RelayCert,
        peer: Option<&LocalRelay>,
        log: PathBuf,
        port: u16,
    ) -> Result<LocalRelay, Attempt> {
        let fail = |what: String, log: &Path| LocalRelayError::Process {
            what,
            log: log.to_path_buf(),
            tail: tail(log),
        };
        let mut cmd = Command::new(bin);
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
                .arg(fingerprint_hex(&p.fingerprint));
        }
        let file = std::fs::File::create(&log).map_err(|e| LocalRelayError::File {
            path: log.clone(),
            why: e.to_string(),
        })?;
        let out = file.try_clone().map_err(|e| LocalRelayError::File {
            path: log.clone(),
            why: e.to_string(),
        })?;
        let child = cmd
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(file)
            .spawn()
            .map_err(|e| fail(format!("did not start ({}): {e}", bin.display()), &log))?;
        let mut relay = LocalRelay {
            child,
            port,
            fingerprint: cert.fingerprint,
            log,
        };
        let until = Instant::now() + Duration::from_secs(20);
        loop {
            // (Its own process, still running, answers: not another one
            // serving the same certificate there.)
            if let Ok(body) = http_get(port, "/certificate.sha256")
                && body
                    .replace(':', "")
                    .eq_ignore_ascii_case(&fingerprint_hex(&cert.fingerprint))
                && matches!(relay.child.try_wait(), Ok(None))
            {
                return Ok(relay);
            }
            if let Ok(Some(status)) = relay.child.try_wait() {
                let e = fail(format!("exited ({status}) before serving"), &relay.log);
                return Err(if relay.log_text().contains("Address already in use") {
                    Attempt::PortTaken(e)
                } else {
                    Attempt::Failed(e)
                });
            }
            if Instant::now() >= until {
                relay.kill();
                return Err(fail(
                    "did not serve its certificate's fingerprint within 20 s".into(),
                    &relay.log,
                )
                .into());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The relay's URL for `path` (`https://127.0.0.1:PORT/PATH`).
    pub fn url(&self, path: &str) -> String {
        format!("https://127.0.0.1:{}/{path}", self.port)
    }

    /// The relay's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
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

impl Drop for LocalRelay {
    fn drop(&mut self) {
        self.kill();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A relay whose port another socket holds is told apart from other
    /// failures, so that [`LocalRelay::start`] tries another port (with
    /// the real relay; skipped without one).
    #[test]
    fn a_relay_finding_its_port_taken_is_tried_again_elsewhere() {
        let Some(bin) = find_relay_binary() else {
            assert!(
                std::env::var_os("PSAO_REQUIRE_RELAY").is_none(),
                "PSAO_REQUIRE_RELAY is set and no moq-relay was found"
            );
            eprintln!("skipped: no moq-relay (set PSAO_MOQ_RELAY or put it on the PATH)");
            return;
        };
        let dir = std::env::temp_dir().join(format!("psao-moq-port-taken-{}", std::process::id()));
        let cert = RelayCert::generate(&dir).expect("a certificate");
        let held = std::net::TcpListener::bind("127.0.0.1:0").expect("a listener");
        let port = held.local_addr().expect("its address").port();
        let taken = LocalRelay::start_once(&bin, &cert, None, dir.join("taken.log"), port);
        assert!(
            matches!(taken, Err(Attempt::PortTaken(_))),
            "a relay on a held port: {}",
            match &taken {
                Ok(r) => format!("served on {}", r.port),
                Err(Attempt::PortTaken(e) | Attempt::Failed(e)) => e.to_string(),
            }
        );
        let relay = LocalRelay::start(&bin, &cert, None, dir.join("free.log")).expect("a relay");
        assert_ne!(relay.port, port);
        drop(relay);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
