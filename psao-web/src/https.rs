//! The HTTPS server of the page: HTTP/1.1 (hyper) over TLS 1.3 and 1.2
//! (tokio-rustls), GET and HEAD of the [`Site`]'s paths only. Its
//! certificate can be replaced while it runs (new connections get the new
//! one). Bounded: at most [`MAX_CONNECTIONS`] at once, a TLS handshake and
//! a request's headers within [`HANDSHAKE_TIMEOUT`].

use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
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

/// How long a TLS handshake, and a request's headers, may take.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

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
        let open = Arc::new(AtomicUsize::new(0));
        let task = tokio::spawn(async move {
            loop {
                let Ok((tcp, remote)) = listener.accept().await else {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                };
                if open.load(Ordering::SeqCst) >= MAX_CONNECTIONS {
                    debug!(%remote, "refused: {MAX_CONNECTIONS} connections open");
                    continue;
                }
                open.fetch_add(1, Ordering::SeqCst);
                let (acceptor, site, open) = (acceptor.clone(), site.clone(), open.clone());
                tokio::spawn(async move {
                    serve_connection(acceptor, tcp, remote, site).await;
                    open.fetch_sub(1, Ordering::SeqCst);
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
        let key = certified(identity)?;
        *self.current.0.write().unwrap_or_else(|e| e.into_inner()) = key;
        Ok(())
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
        .serve_connection(TokioIo::new(tls), service)
        .await;
    if let Err(e) = served {
        debug!(%remote, "HTTPS connection ended: {e}");
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
