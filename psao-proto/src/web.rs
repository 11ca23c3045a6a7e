//! The WebTransport binding (spec/session.md 9): the same session as over
//! `psao/1`, for browsers. A second QUIC endpoint speaks HTTP/3 (ALPN
//! `h3`) through web-transport-quinn; a client's extended CONNECT to
//! [`WEB_PATH`] becomes a WebTransport session, served by the same
//! connection loop and the same fan-out as the native clients.
//!
//! Its certificate is usually short-lived (a browser pins one by its hash
//! only if it is valid for less than 14 days): [`ServerHandle::set_web_identity`]
//! replaces it for new sessions while the running ones go on.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tracing::{debug, info};
use web_transport_quinn as wt;

use crate::server::{ServeError, ServerHandle, serve_connection};
use crate::source::FrameSource;
use crate::tls::{Identity, TlsError, server_config_for};

/// The path of the WebTransport session's URL (spec/session.md 9.1);
/// another path is answered `404`.
pub const WEB_PATH: &str = "/psao";

/// How often the server pings a WebTransport client (spec/session.md 9.1:
/// a page cannot send QUIC PINGs itself).
pub const WEB_KEEP_ALIVE: Duration = Duration::from_secs(1);

/// The QUIC configuration of the WebTransport endpoint.
pub fn web_server_config(
    id: &Identity,
    idle_timeout: Duration,
) -> Result<quinn::ServerConfig, TlsError> {
    let mut config = server_config_for(id, wt::ALPN.as_bytes(), idle_timeout)?;
    let transport = Arc::get_mut(&mut config.transport)
        .ok_or_else(|| TlsError::Config("transport configuration is shared".into()))?;
    // HTTP/3 takes a bidirectional stream for the CONNECT request and
    // unidirectional ones for its control and QPACK streams; the session
    // itself allows one of each (the connection loop closes on more).
    transport.max_concurrent_bidi_streams(4u32.into());
    transport.max_concurrent_uni_streams(4u32.into());
    transport.keep_alive_interval(Some(WEB_KEEP_ALIVE));
    Ok(config)
}

impl<S: FrameSource> ServerHandle<S> {
    /// Listens for WebTransport sessions (spec/session.md 9) on `bind`
    /// with `identity`, beside the `psao/1` endpoint; returns the address.
    /// Their clients share the server's frames, limits and counters.
    pub fn listen_web(
        &mut self,
        bind: SocketAddr,
        identity: &Identity,
    ) -> Result<SocketAddr, ServeError> {
        if self.web_endpoint().is_some() {
            return Err(ServeError::Setting("listen_web (already listening)"));
        }
        let config = web_server_config(identity, self.config().idle_timeout)?;
        let endpoint = quinn::Endpoint::server(config, bind).map_err(|e| ServeError::Bind {
            addr: bind,
            reason: e.to_string(),
        })?;
        let addr = endpoint.local_addr().map_err(|e| ServeError::Bind {
            addr: bind,
            reason: e.to_string(),
        })?;
        let hub = self.hub();
        let acceptor = {
            let endpoint = endpoint.clone();
            tokio::spawn(async move {
                while let Some(incoming) = endpoint.accept().await {
                    let hub = hub.clone();
                    tokio::spawn(async move {
                        let conn = match incoming.await {
                            Ok(c) => c,
                            Err(e) => return debug!("handshake failed: {e}"),
                        };
                        let remote = conn.remote_address();
                        let request = match wt::Request::accept(conn).await {
                            Ok(r) => r,
                            Err(e) => return debug!(%remote, "no WebTransport session: {e}"),
                        };
                        if request.url.path() != WEB_PATH {
                            debug!(%remote, path = request.url.path(), "refused: not {WEB_PATH}");
                            let _ = request.reject(wt::http::StatusCode::NOT_FOUND).await;
                            return;
                        }
                        match request.ok().await {
                            Ok(session) => serve_connection(hub, session).await,
                            Err(e) => debug!(%remote, "WebTransport session failed: {e}"),
                        }
                    });
                }
            })
        };
        info!(%addr, "serving WebTransport");
        self.set_web(endpoint, acceptor);
        Ok(addr)
    }

    /// Replaces the WebTransport endpoint's certificate: sessions opened
    /// from now on see `identity`, open ones keep theirs. An error when
    /// [`listen_web`](Self::listen_web) was not called.
    pub fn set_web_identity(&self, identity: &Identity) -> Result<(), ServeError> {
        let endpoint = self.web_endpoint().ok_or(ServeError::Setting(
            "set_web_identity (not listening for WebTransport)",
        ))?;
        endpoint.set_server_config(Some(web_server_config(
            identity,
            self.config().idle_timeout,
        )?));
        Ok(())
    }
}
