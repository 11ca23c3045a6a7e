//! The HTTPS server of the page: HTTP/1.1 (hyper) over TLS 1.3 and 1.2
//! (tokio-rustls), GET and HEAD of the [`Site`]'s paths only. Its
//! certificate can be replaced while it runs (new connections get the new
//! one). Bounded: at most [`MAX_CONNECTIONS`] at once and
//! [`MAX_PER_ADDRESS`] from one address, a TLS handshake and a request's
//! headers within [`HANDSHAKE_TIMEOUT`], [`MAX_HEADER_BYTES`] and
//! [`MAX_HEADERS`] of headers, and a connection's whole life within
//! [`CONNECTION_LIFETIME`] (a reader that stops reading is cut off).
//! Dropping it stops it and every connection.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, RwLock};
use std::time::Duration;

use bytes::Bytes;
use http_body_util::Full;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use psao_proto::tls::Identity;
use rustls::server::{ClientHello, ResolvesServerCert};
use rustls::sign::CertifiedKey;
use tokio::net::TcpListener;
use tracing::debug;

use crate::site::Site;

/// Most HTTPS connections at once; more are closed at once.
pub const MAX_CONNECTIONS: usize = 256;

/// Most HTTPS connections from one IP address at once.
pub const MAX_PER_ADDRESS: usize = 32;

/// How long a TLS handshake, and a request's headers, may take.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// How long one connection may last (the page's files take well under a
/// second on any link that can carry the stream).
pub const CONNECTION_LIFETIME: Duration = Duration::from_secs(60);

/// The most bytes hyper buffers for a request's head (its minimum).
pub const MAX_HEADER_BYTES: usize = 8192;

/// The most headers in a request.
pub const MAX_HEADERS: usize = 32;

/// Why the HTTPS server could not start.
#[derive(Debug, thiserror::Error)]
pub enum HttpsError {
    /// The socket could not be bound.
    #[error("cannot listen on {addr} (TCP): {reason}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
    /// The certificate or key was refused.
    #[error("TLS: {0}")]
    Tls(String),
}

/// The current certificate, swapped on rotation.
#[derive(Debug)]
struct Current(RwLock<Arc<CertifiedKey>>);

impl ResolvesServerCert for Current {
    fn resolve(&self, _: ClientHello<'_>) -> Option<Arc<CertifiedKey>> {
        Some(self.0.read().unwrap_or_else(|e| e.into_inner()).clone())
    }
}

fn certified(id: &Identity) -> Result<Arc<CertifiedKey>, HttpsError> {
    let provider = rustls::crypto::ring::default_provider();
    CertifiedKey::from_der(id.chain.clone(), id.key.clone_key(), &provider)
        .map(Arc::new)
        .map_err(|e| HttpsError::Tls(e.to_string()))
}

/// A certificate and key checked by [`HttpsServer::prepare`].
#[derive(Debug)]
pub struct PreparedIdentity(Arc<CertifiedKey>);

/// A running HTTPS server; dropping it stops it.
#[derive(Debug)]
pub struct HttpsServer {
    addr: SocketAddr,
    current: Arc<Current>,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for HttpsServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl HttpsServer {
    /// Serves `site` on `bind` (TCP) with `identity`.
    pub async fn start(
        bind: SocketAddr,
        identity: &Identity,
        site: Arc<Site>,
    ) -> Result<HttpsServer, HttpsError> {
        let current = Arc::new(Current(RwLock::new(certified(identity)?)));
        let mut tls = rustls::ServerConfig::builder_with_provider(Arc::new(
            rustls::crypto::ring::default_provider(),
        ))
        .with_safe_default_protocol_versions()
        .map_err(|e| HttpsError::Tls(e.to_string()))?
        .with_no_client_auth()
        .with_cert_resolver(current.clone());
        tls.alpn_protocols = vec![b"http/1.1".to_vec()];
        let acceptor = tokio_rustls::TlsAcceptor::from(Arc::new(tls));
        let listener = TcpListener::bind(bind)
            .await
            .map_err(|e| HttpsError::Bind {
                addr: bind,
                reason: e.to_string(),
            })?;
        let addr = listener.local_addr().map_err(|e| HttpsError::Bind {
            addr: bind,
            reason: e.to_string(),
        })?;
        let task = tokio::spawn(async move {
            // The connections' tasks: aborted with this one (a dropped
            // server closes them all).
            let mut connections = tokio::task::JoinSet::new();
            let mut per_address: HashMap<IpAddr, usize> = HashMap::new();
            loop {
                let accepted = tokio::select! {
                    a = listener.accept() => a,
                    Some(done) = connections.join_next() => {
                        if let Ok(ip) = done {
                            forget(&mut per_address, ip);
                        }
                        continue;
                    }
                };
                let Ok((tcp, remote)) = accepted else {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                };
                let from = per_address.get(&remote.ip()).copied().unwrap_or(0);
                if connections.len() >= MAX_CONNECTIONS || from >= MAX_PER_ADDRESS {
                    debug!(%remote, "refused: {} connections open, {from} from it", connections.len());
                    continue;
                }
                *per_address.entry(remote.ip()).or_insert(0) += 1;
                let (acceptor, site) = (acceptor.clone(), site.clone());
                connections.spawn(async move {
                    let served = serve_connection(acceptor, tcp, remote, site);
                    if tokio::time::timeout(CONNECTION_LIFETIME, served)
                        .await
                        .is_err()
                    {
                        debug!(%remote, "HTTPS connection cut after {CONNECTION_LIFETIME:?}");
                    }
                    remote.ip()
                });
            }
        });
        Ok(HttpsServer {
            addr,
            current,
            task,
        })
    }

    /// Where it listens.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// New connections get `identity` from now on.
    pub fn set_identity(&self, identity: &Identity) -> Result<(), HttpsError> {
        let prepared = Self::prepare(identity)?;
        self.install(prepared);
        Ok(())
    }

    /// Checks `identity` and readies it for [`install`](Self::install),
    /// which cannot fail (to swap it together with other servers).
    pub fn prepare(identity: &Identity) -> Result<PreparedIdentity, HttpsError> {
        certified(identity).map(PreparedIdentity)
    }

    /// New connections get the prepared identity from now on.
    pub fn install(&self, prepared: PreparedIdentity) {
        *self.current.0.write().unwrap_or_else(|e| e.into_inner()) = prepared.0;
    }
}

async fn serve_connection(
    acceptor: tokio_rustls::TlsAcceptor,
    tcp: tokio::net::TcpStream,
    remote: SocketAddr,
    site: Arc<Site>,
) {
    let tls = match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(tcp)).await {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => return debug!(%remote, "TLS handshake failed: {e}"),
        Err(_) => return debug!(%remote, "TLS handshake timed out"),
    };
    let service = hyper::service::service_fn(move |req| {
        let site = site.clone();
        async move { Ok::<_, std::convert::Infallible>(respond(&site, &req)) }
    });
    let served = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(HANDSHAKE_TIMEOUT)
        .max_buf_size(MAX_HEADER_BYTES)
        .max_headers(MAX_HEADERS)
        .serve_connection(TokioIo::new(tls), service)
        .await;
    if let Err(e) = served {
        debug!(%remote, "HTTPS connection ended: {e}");
    }
}

/// One connection from `ip` ended.
fn forget(per_address: &mut HashMap<IpAddr, usize>, ip: IpAddr) {
    if let Some(n) = per_address.get_mut(&ip) {
        *n -= 1;
        if *n == 0 {
            per_address.remove(&ip);
        }
    }
}

/// The response to one request.
fn respond<B>(site: &Site, req: &Request<B>) -> Response<Full<Bytes>> {
    let plain = |status: StatusCode, text: &str| {
        let mut r = Response::new(Full::new(Bytes::from(text.to_string())));
        *r.status_mut() = status;
        r.headers_mut().insert(
            hyper::header::CONTENT_TYPE,
            hyper::header::HeaderValue::from_static("text/plain; charset=utf-8"),
        );
        r
    };
    let head = req.method() == Method::HEAD;
    if req.method() != Method::GET && !head {
        let mut r = plain(StatusCode::METHOD_NOT_ALLOWED, "GET or HEAD only\n");
        r.headers_mut().insert(
            hyper::header::ALLOW,
            hyper::header::HeaderValue::from_static("GET, HEAD"),
        );
        return r;
    }
    let Some((kind, bytes)) = site.get(req.uri().path()) else {
        return plain(StatusCode::NOT_FOUND, "not found\n");
    };
    let len = bytes.len();
    let mut r = Response::new(Full::new(if head { Bytes::new() } else { bytes }));
    let h = r.headers_mut();
    h.insert(
        hyper::header::CONTENT_TYPE,
        hyper::header::HeaderValue::from_static(kind),
    );
    h.insert(hyper::header::CONTENT_LENGTH, len.into());
    // The config names the current certificate: never cached.
    h.insert(
        hyper::header::CACHE_CONTROL,
        hyper::header::HeaderValue::from_static("no-store"),
    );
    r
}
