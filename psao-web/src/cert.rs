//! The page's certificate: ECDSA P-256, self-signed, valid for less than
//! 14 days (a browser pins such a certificate by its SHA-256 with
//! `serverCertificateHashes`), replaced before it expires.

use std::time::{Duration, SystemTime};

use base64::Engine;
use psao_proto::tls::{Identity, fingerprint_hex};
use rustls::pki_types::{PrivateKeyDer, PrivatePkcs8KeyDer};
use sha2::{Digest, Sha256};

/// The longest validity a browser accepts for a certificate pinned by its
/// hash (less than 14 days).
pub const MAX_VALIDITY: Duration = Duration::from_secs(14 * 24 * 3600 - 3600);

/// A certificate for the WebTransport endpoint and the HTTPS server.
#[derive(Debug)]
pub struct WebCertificate {
    /// The certificate and key, for both servers.
    pub identity: Identity,
    /// SHA-256 of the certificate's DER bytes (what `serverCertificateHashes`
    /// and psao's `--fingerprint` pin).
    pub fingerprint: [u8; 32],
    /// Base64 of the SHA-256 of its SubjectPublicKeyInfo: Chromium's
    /// `--ignore-certificate-errors-spki-list` takes it, to load the HTTPS
    /// page without a warning.
    pub spki_sha256: String,
    /// When it stops being valid.
    pub not_after: SystemTime,
}

/// Why a certificate could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CertError {
    /// The validity asked for is not what a browser accepts.
    #[error("certificate validity {0:?}: must be above 1 minute and below 14 days")]
    Validity(Duration),
    /// rcgen failed.
    #[error("cannot make a certificate: {0}")]
    Generate(String),
}

impl WebCertificate {
    /// A fresh P-256 key and a certificate for `localhost` and 127.0.0.1,
    /// valid from a minute ago (clocks differ a little) for `valid_for`.
    pub fn generate(valid_for: Duration) -> Result<WebCertificate, CertError> {
        let key = rcgen::KeyPair::generate_for(&rcgen::PKCS_ECDSA_P256_SHA256)
            .map_err(|e| CertError::Generate(e.to_string()))?;
        Self::sign(key, valid_for)
    }

    /// A new certificate for the same key, valid from a minute ago for
    /// `valid_for`: its hash changes, its SPKI hash (what Chromium's
    /// `--ignore-certificate-errors-spki-list` was given) does not.
    pub fn renew(&self, valid_for: Duration) -> Result<WebCertificate, CertError> {
        let der = self.pkcs8_key()?;
        let key = rcgen::KeyPair::try_from(&der).map_err(|e| CertError::Generate(e.to_string()))?;
        Self::sign(key, valid_for)
    }

    /// A copy of the key (PKCS#8).
    fn pkcs8_key(&self) -> Result<PrivatePkcs8KeyDer<'static>, CertError> {
        match &self.identity.key {
            PrivateKeyDer::Pkcs8(der) => Ok(der.clone_key()),
            _ => Err(CertError::Generate("the key is not PKCS#8".into())),
        }
    }

    fn sign(key: rcgen::KeyPair, valid_for: Duration) -> Result<WebCertificate, CertError> {
        if valid_for <= Duration::from_secs(60) || valid_for > MAX_VALIDITY {
            return Err(CertError::Validity(valid_for));
        }
        let gen_err = |e: rcgen::Error| CertError::Generate(e.to_string());
        let mut params =
            rcgen::CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()])
                .map_err(gen_err)?;
        let now = time::OffsetDateTime::now_utc();
        params.not_before = now - time::Duration::minutes(1);
        params.not_after = now + valid_for;
        let cert = params.self_signed(&key).map_err(gen_err)?;
        let der = cert.der().clone();
        let fingerprint: [u8; 32] = Sha256::digest(der.as_ref()).into();
        let spki_sha256 = base64::engine::general_purpose::STANDARD.encode(Sha256::digest(
            rcgen::PublicKeyData::subject_public_key_info(&key),
        ));
        Ok(WebCertificate {
            identity: Identity {
                chain: vec![der],
                key: PrivateKeyDer::Pkcs8(key.serialize_der().into()),
            },
            fingerprint,
            spki_sha256,
            not_after: SystemTime::now() + valid_for,
        })
    }

    /// The fingerprint as 64 lowercase hex digits.
    pub fn fingerprint_hex(&self) -> String {
        fingerprint_hex(&self.fingerprint)
    }
}

/// How long certificates are valid and when they are replaced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rotation {
    /// Validity of each certificate.
    pub valid_for: Duration,
    /// A new certificate replaces the current one this long after it was
    /// made (before it expires: sessions opened under the old one keep it).
    pub replace_after: Duration,
}

impl Default for Rotation {
    /// Valid 10 days, replaced after 7.
    fn default() -> Self {
        Rotation {
            valid_for: Duration::from_secs(10 * 24 * 3600),
            replace_after: Duration::from_secs(7 * 24 * 3600),
        }
    }
}

impl Rotation {
    /// Checks the two durations: a validity a browser accepts, and a
    /// replacement before expiry.
    pub fn check(&self) -> Result<(), CertError> {
        if self.valid_for <= Duration::from_secs(60) || self.valid_for > MAX_VALIDITY {
            return Err(CertError::Validity(self.valid_for));
        }
        if self.replace_after.is_zero() || self.replace_after >= self.valid_for {
            return Err(CertError::Generate(format!(
                "replace_after {:?} must be above 0 and below the validity {:?}",
                self.replace_after, self.valid_for
            )));
        }
        Ok(())
    }

    /// Runs until the returned task is aborted: `replace_after` after
    /// `current` was made (by the wall clock, which a suspended machine's
    /// sleep does not stop: it is looked at at least hourly), a renewal
    /// of it (the same key) goes to `install` (which hands it to every
    /// server that presents it), and so on from there. A failure to make
    /// one is logged and retried a minute later; the current certificate
    /// stays until then.
    pub fn spawn(
        self,
        current: &WebCertificate,
        install: impl Fn(WebCertificate) + Send + 'static,
    ) -> Result<tokio::task::JoinHandle<()>, CertError> {
        self.check()?;
        let key = current.pkcs8_key()?;
        let ahead = self.valid_for - self.replace_after;
        let mut due = current
            .not_after
            .checked_sub(ahead)
            .unwrap_or(SystemTime::now());
        Ok(tokio::spawn(async move {
            loop {
                let left = due
                    .duration_since(SystemTime::now())
                    .unwrap_or(Duration::ZERO);
                if !left.is_zero() {
                    tokio::time::sleep(left.min(Duration::from_secs(3600))).await;
                    continue;
                }
                let renewed = rcgen::KeyPair::try_from(&key)
                    .map_err(|e| CertError::Generate(e.to_string()))
                    .and_then(|k| WebCertificate::sign(k, self.valid_for));
                match renewed {
                    Ok(c) => {
                        tracing::info!(fingerprint = %c.fingerprint_hex(), "certificate replaced");
                        due = c.not_after.checked_sub(ahead).unwrap_or(SystemTime::now());
                        install(c);
                    }
                    Err(e) => {
                        tracing::warn!("cannot replace the certificate: {e}");
                        due = SystemTime::now() + Duration::from_secs(60);
                    }
                }
            }
        }))
    }
}
