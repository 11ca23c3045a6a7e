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
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use tracing::{debug, info};
use web_transport_quinn as wt;

use crate::server::{H3_NO_ERROR, ServeError, ServerHandle, serve_connection};
use crate::source::FrameSource;
use crate::tls::{Identity, TlsError, server_config_for};

/// The path of the WebTransport session's URL (spec/session.md 9.1);
/// another path is answered `404`.
pub const WEB_PATH: &str = "/psao";

/// How often the server pings a WebTransport client (spec/session.md 9.1:
/// a page cannot send QUIC PINGs itself).
pub const WEB_KEEP_ALIVE: Duration = Duration::from_secs(1);

/// Bytes a WebTransport client may send ahead on one stream.
pub const WEB_STREAM_WINDOW: u32 = 64 * 1024;

/// Bytes a WebTransport client may send ahead on all its streams.
pub const WEB_CONNECTION_WINDOW: u32 = 256 * 1024;

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
    // A client sends control messages only (at most 1026 bytes each, at
    // the rates of section 6) and HTTP/3's few bytes: small windows bound
    // what one connection can park in the server. Datagrams are
    // advertised, as browsers require, with room for one.
    transport.stream_receive_window(WEB_STREAM_WINDOW.into());
    transport.receive_window(WEB_CONNECTION_WINDOW.into());
    transport.datagram_receive_buffer_size(Some(1500));
    transport.keep_alive_interval(Some(WEB_KEEP_ALIVE));
    Ok(config)
}

/// How long a connection may take from its first packet to its session's
/// `200` (QUIC and HTTP/3 handshakes, the CONNECT).
pub const SETUP_TIMEOUT: Duration = Duration::from_secs(10);

/// Connections setting up at once beyond the server's `max_clients`.
pub const MAX_SETTING_UP: usize = 64;

/// The session of one incoming connection: the handshakes, then the
/// CONNECT, answered `200` on [`WEB_PATH`] and `404` elsewhere (`None`
/// then, or when a step failed).
async fn set_up(incoming: quinn::Incoming) -> Option<wt::Session> {
    let conn = match incoming.await {
        Ok(c) => c,
        Err(e) => {
            debug!("handshake failed: {e}");
            return None;
        }
    };
    let remote = conn.remote_address();
    let request = match wt::Request::accept(conn.clone()).await {
        Ok(r) => r,
        Err(e) => {
            debug!(%remote, "no WebTransport session: {e}");
            return None;
        }
    };
    if request.url.path() != WEB_PATH || request.url.query().is_some() {
        debug!(%remote, url = %request.url, "refused: not {WEB_PATH}");
        let _ = request.reject(wt::http::StatusCode::NOT_FOUND).await;
        // The 404 goes out before the connection closes: the client
        // closes it, or it closes after a moment.
        let _ = tokio::time::timeout(Duration::from_secs(1), conn.closed()).await;
        conn.close(quinn::VarInt::from_u32(H3_NO_ERROR), b"not found");
        return None;
    }
    match request.ok().await {
        Ok(session) => Some(session),
        Err(e) => {
            debug!(%remote, "WebTransport session failed: {e}");
            None
        }
    }
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
            // Connections between the QUIC handshake and their session's
            // end: at most max_clients plus the ones still setting up.
            let open = Arc::new(AtomicUsize::new(0));
            let most = self.config().max_clients.saturating_add(MAX_SETTING_UP);
            tokio::spawn(async move {
                while let Some(incoming) = endpoint.accept().await {
                    if open.load(Ordering::SeqCst) >= most {
                        debug!(remote = %incoming.remote_address(), "refused: {most} connections open");
                        incoming.refuse();
                        continue;
                    }
                    open.fetch_add(1, Ordering::SeqCst);
                    let (hub, open) = (hub.clone(), open.clone());
                    tokio::spawn(async move {
                        // The QUIC and HTTP/3 handshakes and the CONNECT,
                        // within SETUP_TIMEOUT (the server's pings would
                        // keep a silent connection from idling out).
                        match tokio::time::timeout(SETUP_TIMEOUT, set_up(incoming)).await {
                            Ok(Some(session)) => serve_connection(hub, session).await,
                            Ok(None) => {}
                            Err(_) => debug!("WebTransport setup timed out"),
                        }
                        open.fetch_sub(1, Ordering::SeqCst);
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
