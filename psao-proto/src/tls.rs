//! TLS for the session: the server's certificate (from files, or a
//! generated self-signed one whose SHA-256 fingerprint clients pin), and
//! the QUIC configurations with ALPN `psao/1`.

use std::path::Path;
use std::sync::Arc;

use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::CryptoProvider;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName, UnixTime};
use rustls::{DigitallySignedStruct, SignatureScheme};
use sha2::{Digest, Sha256};

/// The server's QUIC send window per connection (bytes written to a
/// client and not yet acknowledged by it).
pub const SEND_WINDOW: u64 = 512 * 1024;

/// The ALPN protocol id.
pub const ALPN: &[u8] = b"psao/1";

/// Errors setting up TLS.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TlsError {
    /// A certificate or key file could not be read or parsed.
    #[error("{path}: {reason}")]
    File {
        /// The file.
        path: String,
        /// What was wrong.
        reason: String,
    },
    /// A fingerprint is not 64 hex digits.
    #[error("fingerprint `{0}` is not 64 hex digits (SHA-256)")]
    Fingerprint(String),
    /// rustls or quinn refused the configuration.
    #[error("TLS configuration: {0}")]
    Config(String),
}

/// A certificate chain and its private key.
#[derive(Debug)]
pub struct Identity {
    /// The chain, end entity first.
    pub chain: Vec<CertificateDer<'static>>,
    /// The key.
    pub key: PrivateKeyDer<'static>,
}

impl Identity {
    /// A fresh self-signed certificate for `localhost` and 127.0.0.1.
    pub fn self_signed() -> Result<Identity, TlsError> {
        let ck = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
            .map_err(|e| TlsError::Config(e.to_string()))?;
        Ok(Identity {
            chain: vec![ck.cert.der().clone()],
            key: PrivateKeyDer::Pkcs8(ck.signing_key.serialize_der().into()),
        })
    }

    /// A fresh self-signed certificate for `localhost` and 127.0.0.1, with
    /// its certificate and key in PEM too (for another server that reads
    /// files, such as a relay of a test cluster that shares one
    /// certificate).
    pub fn self_signed_pem() -> Result<(Identity, String, String), TlsError> {
        let ck = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])
            .map_err(|e| TlsError::Config(e.to_string()))?;
        let pems = (ck.cert.pem(), ck.signing_key.serialize_pem());
        let id = Identity {
            chain: vec![ck.cert.der().clone()],
            key: PrivateKeyDer::Pkcs8(ck.signing_key.serialize_der().into()),
        };
        Ok((id, pems.0, pems.1))
    }

    /// Reads a PEM certificate chain and a PEM private key.
    pub fn from_pem_files(cert: &Path, key: &Path) -> Result<Identity, TlsError> {
        let file_err = |p: &Path, r: String| TlsError::File {
            path: p.display().to_string(),
            reason: r,
        };
        let chain = CertificateDer::pem_file_iter(cert)
            .map_err(|e| file_err(cert, e.to_string()))?
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| file_err(cert, e.to_string()))?;
        if chain.is_empty() {
            return Err(file_err(cert, "no certificate in the file".into()));
        }
        let key = PrivateKeyDer::from_pem_file(key).map_err(|e| file_err(key, e.to_string()))?;
        Ok(Identity { chain, key })
    }

    /// SHA-256 of the end-entity certificate's DER bytes.
    pub fn fingerprint(&self) -> [u8; 32] {
        fingerprint(&self.chain[0])
    }
}

/// SHA-256 of a certificate's DER bytes.
pub fn fingerprint(cert: &CertificateDer<'_>) -> [u8; 32] {
    Sha256::digest(cert.as_ref()).into()
}

/// A fingerprint as 64 lowercase hex digits.
pub fn fingerprint_hex(f: &[u8; 32]) -> String {
    f.iter().map(|b| format!("{b:02x}")).collect()
}

/// Parses 64 hex digits (colons allowed between bytes).
pub fn parse_fingerprint(s: &str) -> Result<[u8; 32], TlsError> {
    let hex: String = s.chars().filter(|c| *c != ':').collect();
    if hex.len() != 64 || !hex.is_ascii() {
        return Err(TlsError::Fingerprint(s.to_string()));
    }
    let mut out = [0u8; 32];
    for (i, b) in out.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16)
            .map_err(|_| TlsError::Fingerprint(s.to_string()))?;
    }
    Ok(out)
}

fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// The server's QUIC configuration; a connection silent for
/// `idle_timeout` is dropped.
pub fn server_config(
    id: &Identity,
    idle_timeout: std::time::Duration,
) -> Result<quinn::ServerConfig, TlsError> {
    let mut config = server_config_for(id, ALPN, idle_timeout)?;
    let transport = Arc::get_mut(&mut config.transport)
        .ok_or_else(|| TlsError::Config("transport configuration is shared".into()))?;
    // Clients open one bidirectional stream and no unidirectional one.
    transport.max_concurrent_bidi_streams(1u32.into());
    transport.max_concurrent_uni_streams(0u32.into());
    // Bytes written but not yet acknowledged, per connection: with the
    // outbox bound this caps what a stalled client costs the server.
    transport.send_window(SEND_WINDOW);
    // No QUIC datagrams in version 1: do not advertise them.
    transport.datagram_receive_buffer_size(None);
    Ok(config)
}

/// A QUIC server configuration with TLS 1.3 on `id`, the single ALPN
/// `alpn`, the idle timeout and [`SEND_WINDOW`]; each binding sets its
/// stream limits on it.
pub(crate) fn server_config_for(
    id: &Identity,
    alpn: &[u8],
    idle_timeout: std::time::Duration,
) -> Result<quinn::ServerConfig, TlsError> {
    let mut tls = rustls::ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| TlsError::Config(e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(id.chain.clone(), id.key.clone_key())
        .map_err(|e| TlsError::Config(e.to_string()))?;
    tls.alpn_protocols = vec![alpn.to_vec()];
    let quic = quinn::crypto::rustls::QuicServerConfig::try_from(tls)
        .map_err(|e| TlsError::Config(e.to_string()))?;
    let mut config = quinn::ServerConfig::with_crypto(Arc::new(quic));
    let transport = Arc::get_mut(&mut config.transport)
        .ok_or_else(|| TlsError::Config("transport configuration is shared".into()))?;
    transport.send_window(SEND_WINDOW);
    transport.max_idle_timeout(Some(
        quinn::IdleTimeout::try_from(idle_timeout)
            .map_err(|e| TlsError::Config(format!("idle timeout: {e}")))?,
    ));
    Ok(config)
}

/// How a client trusts the server.
#[derive(Clone, Debug)]
pub enum Trust {
    /// The end-entity certificate must have this SHA-256.
    Fingerprint([u8; 32]),
    /// The chain must verify against these roots, for this server name.
    Roots {
        /// Trusted root certificates.
        roots: Vec<CertificateDer<'static>>,
        /// The name the certificate must carry (the host connected to).
        name: String,
    },
}

impl Trust {
    /// The server name to send and check (SNI `localhost` when pinning).
    pub fn server_name(&self) -> &str {
        match self {
            Trust::Fingerprint(_) => "localhost",
            Trust::Roots { name, .. } => name,
        }
    }
}

/// The TLS side of a QUIC client that trusts a server as `trust` says and
/// offers these ALPNs, most preferred first (psao's own: [`ALPN`]; the MoQ
/// binding in psao-moq offers MoQ's).
pub fn client_crypto(
    trust: &Trust,
    alpns: &[&[u8]],
) -> Result<quinn::crypto::rustls::QuicClientConfig, TlsError> {
    quinn::crypto::rustls::QuicClientConfig::try_from(client_tls(trust, alpns)?)
        .map_err(|e| TlsError::Config(e.to_string()))
}

/// The TLS 1.3 client configuration of [`client_crypto`], for a client
/// over TCP too (the page's HTTPS server in psao-web's tests).
pub fn client_tls(trust: &Trust, alpns: &[&[u8]]) -> Result<rustls::ClientConfig, TlsError> {
    let builder = rustls::ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| TlsError::Config(e.to_string()))?;
    let mut tls = match trust {
        Trust::Fingerprint(f) => builder
            .dangerous()
            .with_custom_certificate_verifier(Arc::new(Pinned {
                fingerprint: *f,
                provider: provider(),
            }))
            .with_no_client_auth(),
        Trust::Roots { roots, .. } => {
            let mut store = rustls::RootCertStore::empty();
            for r in roots {
                store
                    .add(r.clone())
                    .map_err(|e| TlsError::Config(e.to_string()))?;
            }
            builder.with_root_certificates(store).with_no_client_auth()
        }
    };
    tls.alpn_protocols = alpns.iter().map(|a| a.to_vec()).collect();
    Ok(tls)
}

/// The client's QUIC configuration.
pub fn client_config(trust: &Trust) -> Result<quinn::ClientConfig, TlsError> {
    let quic = client_crypto(trust, &[ALPN])?;
    let mut config = quinn::ClientConfig::new(Arc::new(quic));
    let mut transport = quinn::TransportConfig::default();
    // The server opens one unidirectional stream (frames) and no
    // bidirectional one.
    transport.max_concurrent_bidi_streams(0u32.into());
    transport.max_concurrent_uni_streams(1u32.into());
    // Keep a quiet session alive through the server's idle timeout.
    transport.keep_alive_interval(Some(std::time::Duration::from_secs(1)));
    transport.datagram_receive_buffer_size(None);
    config.transport_config(Arc::new(transport));
    Ok(config)
}

/// Accepts exactly the certificate with a pinned fingerprint (and checks
/// the handshake signatures against it).
#[derive(Debug)]
struct Pinned {
    fingerprint: [u8; 32],
    provider: Arc<CryptoProvider>,
}

impl ServerCertVerifier for Pinned {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        if fingerprint(end_entity) == self.fingerprint {
            Ok(ServerCertVerified::assertion())
        } else {
            Err(rustls::Error::InvalidCertificate(
                rustls::CertificateError::ApplicationVerificationFailure,
            ))
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls12_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(
            message,
            cert,
            dss,
            &self.provider.signature_verification_algorithms,
        )
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.provider
            .signature_verification_algorithms
            .supported_schemes()
    }
}
