//! A relay's URL, and the raw QUIC connection a MoQ session runs over
//! (moq-lite by ALPN, spec/moq.md 7).

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use psao_proto::tls::{TlsError, Trust, client_crypto};

/// Why publishing or subscribing failed.
#[derive(Debug, thiserror::Error)]
pub enum MoqError {
    /// The relay URL is not `https://HOST[:PORT][/PATH]`.
    #[error("relay URL {url:?}: {why}")]
    Url {
        /// The URL given.
        url: String,
        /// What is wrong with it.
        why: &'static str,
    },
    /// The relay's host did not resolve.
    #[error("relay host {host:?} did not resolve: {why}")]
    Resolve {
        /// The host.
        host: String,
        /// The resolver's error.
        why: String,
    },
    /// TLS configuration.
    #[error("TLS: {0}")]
    Tls(#[from] TlsError),
    /// The QUIC connection to the relay.
    #[error("QUIC connection to the relay {addr}: {why}")]
    Connect {
        /// The relay's address.
        addr: SocketAddr,
        /// What failed.
        why: String,
    },
    /// The MoQ session (handshake, announce, subscription).
    #[error("MoQ: {0}")]
    Moq(#[from] moq_net::Error),
    /// The broadcast cannot be followed (its catalog).
    #[error(transparent)]
    Follow(#[from] crate::FollowError),
    /// A frame of the broadcast declared more bytes than the catalog allows
    /// (it is not read).
    #[error("a frame of {size} bytes, above the catalog's {max}")]
    FrameTooLarge {
        /// Its declared size.
        size: u64,
        /// The catalog's limit.
        max: u64,
    },
    /// The frame source failed.
    #[error("frame source: {0}")]
    Source(psao_proto::SourceError),
    /// Nothing happened for this long.
    #[error("timed out: {0}")]
    Timeout(&'static str),
}

/// A relay's URL: `https://HOST[:PORT][/PATH]` (port 443 by default). For a
/// subscriber the path is the broadcast; a publisher names its broadcast
/// itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RelayUrl {
    /// Host name or address (an IPv6 address without brackets).
    pub host: String,
    /// UDP port.
    pub port: u16,
    /// The path without its leading `/` (may be empty).
    pub path: String,
}

impl std::str::FromStr for RelayUrl {
    type Err = MoqError;

    fn from_str(url: &str) -> Result<RelayUrl, MoqError> {
        let bad = |why| MoqError::Url {
            url: url.to_string(),
            why,
        };
        let rest = url
            .strip_prefix("https://")
            .ok_or_else(|| bad("it does not start with https://"))?;
        if rest.contains('?') || rest.contains('#') {
            return Err(bad("a query or fragment (not supported)"));
        }
        let (authority, path) = rest.split_once('/').unwrap_or((rest, ""));
        let (host, port) = if let Some(v6) = authority.strip_prefix('[') {
            let (host, after) = v6.split_once(']').ok_or_else(|| bad("an unclosed ["))?;
            match after {
                "" => (host, None),
                p => (
                    host,
                    Some(p.strip_prefix(':').ok_or_else(|| bad("junk after ]"))?),
                ),
            }
        } else {
            match authority.rsplit_once(':') {
                Some((h, p)) => (h, Some(p)),
                None => (authority, None),
            }
        };
        if host.is_empty() {
            return Err(bad("no host"));
        }
        let port = match port {
            None => 443,
            Some(p) => p
                .parse()
                .map_err(|_| bad("the port is not a number 0..=65535"))?,
        };
        Ok(RelayUrl {
            host: host.to_string(),
            port,
            path: path.trim_matches('/').to_string(),
        })
    }
}

impl std::fmt::Display for RelayUrl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.host.contains(':') {
            write!(f, "https://[{}]:{}/{}", self.host, self.port, self.path)
        } else {
            write!(f, "https://{}:{}/{}", self.host, self.port, self.path)
        }
    }
}

/// The moq-lite ALPNs this build offers, newest first: moq-net's own list
/// without the IETF drafts and without `moql` (versions that negotiate in
/// SETUP), spec/moq.md 7.
pub fn alpns() -> Vec<&'static [u8]> {
    moq_net::ALPNS
        .iter()
        .filter(|a| a.starts_with("moq-lite-"))
        .map(|a| a.as_bytes())
        .collect()
}

/// How long resolving the relay's host, and then the QUIC handshake with
/// it, may each take.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// How long the MoQ setup over an established connection may take.
pub const SETUP_TIMEOUT: Duration = Duration::from_secs(5);

/// Opens a QUIC connection to the relay, offering the moq-lite ALPNs, and
/// wraps it as a session for moq-net.
pub async fn dial(url: &RelayUrl, trust: &Trust) -> Result<web_transport_quinn::Session, MoqError> {
    let addr = tokio::time::timeout(
        CONNECT_TIMEOUT,
        tokio::net::lookup_host((url.host.as_str(), url.port)),
    )
    .await
    .map_err(|_| MoqError::Timeout("resolving the relay's host"))?
    .map_err(|e| MoqError::Resolve {
        host: url.host.clone(),
        why: e.to_string(),
    })?
    .next()
    .ok_or_else(|| MoqError::Resolve {
        host: url.host.clone(),
        why: "no address".into(),
    })?;
    let connect_err = |why: String| MoqError::Connect { addr, why };
    let crypto = client_crypto(trust, &alpns())?;
    let mut config = quinn::ClientConfig::new(Arc::new(crypto));
    let mut transport = quinn::TransportConfig::default();
    // moq-lite opens a stream per subscription and per group.
    transport.max_concurrent_bidi_streams(256u32.into());
    transport.max_concurrent_uni_streams(1024u32.into());
    transport.keep_alive_interval(Some(Duration::from_secs(1)));
    transport.max_idle_timeout(Some(
        quinn::IdleTimeout::try_from(Duration::from_secs(10)).expect("10 s fits"),
    ));
    config.transport_config(Arc::new(transport));
    let bind: SocketAddr = if addr.is_ipv6() {
        "[::]:0".parse().expect("an address")
    } else {
        "0.0.0.0:0".parse().expect("an address")
    };
    let endpoint = quinn::Endpoint::client(bind).map_err(|e| connect_err(e.to_string()))?;
    let name = match trust {
        Trust::Fingerprint(_) => trust.server_name(),
        Trust::Roots { .. } => url.host.as_str(),
    };
    let connecting = endpoint
        .connect_with(config, addr, name)
        .map_err(|e| connect_err(e.to_string()))?;
    let conn = tokio::time::timeout(CONNECT_TIMEOUT, connecting)
        .await
        .map_err(|_| MoqError::Timeout("the QUIC handshake with the relay"))?
        .map_err(|e| connect_err(e.to_string()))?;
    let session = web_transport_quinn::Session::raw(conn);
    if session.protocol().is_none() {
        // No moq-lite ALPN agreed: moq-net would fall back to a SETUP
        // exchange this binding does not use (spec/moq.md 2).
        return Err(connect_err("the relay agreed on no moq-lite ALPN".into()));
    }
    Ok(session)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relay_urls_parse_with_their_parts() {
        let u: RelayUrl = "https://127.0.0.1:4443/psao/default".parse().unwrap();
        assert_eq!(
            u,
            RelayUrl {
                host: "127.0.0.1".into(),
                port: 4443,
                path: "psao/default".into()
            }
        );
        let u: RelayUrl = "https://relay.example".parse().unwrap();
        assert_eq!((u.port, u.path.as_str()), (443, ""));
        let u: RelayUrl = "https://[::1]:9/x/".parse().unwrap();
        assert_eq!((u.host.as_str(), u.port, u.path.as_str()), ("::1", 9, "x"));
        assert_eq!(u.to_string(), "https://[::1]:9/x");
        let u: RelayUrl = "https://a//psao/x/".parse().unwrap();
        assert_eq!(u.path, "psao/x");
    }

    #[test]
    fn bad_relay_urls_say_what_is_wrong() {
        for (url, why) in [
            ("http://a:1/", "https://"),
            ("https://:1/", "no host"),
            ("https://a:99999/", "port"),
            ("https://[::1/", "unclosed"),
            ("https://a/b?jwt=x", "query"),
            ("https://a?jwt=x", "query"),
            ("https://a:443#f", "query"),
        ] {
            let e = url.parse::<RelayUrl>().unwrap_err().to_string();
            assert!(e.contains(why), "{url}: {e}");
        }
    }

    #[test]
    fn only_moq_lite_is_offered() {
        let a = alpns();
        assert!(!a.is_empty());
        assert!(a.iter().all(|a| a.starts_with(b"moq-lite-")));
    }
}
