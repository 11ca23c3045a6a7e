//! What the reference server needs of a session's transport, so that one
//! connection loop serves both bindings of spec/session.md: a QUIC
//! connection (`psao/1`, section 2) and a WebTransport session (section 9).
//! Each binding is a few lines over its library's types; the session logic
//! stays in [`crate::server`].

use std::future::Future;
use std::net::SocketAddr;

/// How a client is connected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Binding {
    /// QUIC with ALPN `psao/1` (spec/session.md 2).
    Native,
    /// A WebTransport session (spec/session.md 9).
    WebTransport,
}

/// A read from a receive stream.
pub(crate) enum Read {
    /// This many bytes were read into the buffer.
    Data(usize),
    /// The peer finished the stream.
    Finished,
    /// The peer reset the stream.
    Reset,
    /// The connection is gone (closed, lost or timed out).
    Lost,
}

/// The sending half of a stream.
pub(crate) trait LinkSend: Send + 'static {
    /// Writes all of `bytes`; `Err` when the stream was stopped or the
    /// connection is gone.
    fn write_all(&mut self, bytes: &[u8]) -> impl Future<Output = Result<(), ()>> + Send;
    /// Ends the stream after what was written.
    fn finish(&mut self);
    /// Resolves once the peer acknowledged the finish or stopped the
    /// stream (or the connection is gone).
    fn stopped(&mut self) -> impl Future<Output = ()> + Send;
}

/// The receiving half of a stream.
pub(crate) trait LinkRecv: Send + 'static {
    /// Reads what has arrived, at most `buf.len()` bytes.
    fn read(&mut self, buf: &mut [u8]) -> impl Future<Output = Read> + Send;
}

/// One client's session: its streams and how to close it.
pub(crate) trait Link: Clone + Send + Sync + 'static {
    /// The sending half of a stream.
    type Send: LinkSend;
    /// The receiving half of a stream.
    type Recv: LinkRecv;
    /// The next bidirectional stream the client opens.
    fn accept_bi(&self) -> impl Future<Output = Result<(Self::Send, Self::Recv), String>> + Send;
    /// Resolves when the client opens any further stream (or the
    /// connection is gone).
    fn any_stream(&self) -> impl Future<Output = ()> + Send;
    /// Opens the server's unidirectional stream.
    fn open_uni(&self) -> impl Future<Output = Result<Self::Send, ()>> + Send;
    /// Closes the session with a code of spec/session.md 7.
    fn close(&self, code: u32, reason: &[u8]);
    /// Resolves when the session is closed.
    fn closed(&self) -> impl Future<Output = ()> + Send;
    /// The client's address.
    fn remote_address(&self) -> SocketAddr;
    /// UDP bytes the connection sent so far.
    fn udp_sent(&self) -> u64;
    /// Which binding this is.
    const BINDING: Binding;
}

impl LinkSend for quinn::SendStream {
    async fn write_all(&mut self, bytes: &[u8]) -> Result<(), ()> {
        quinn::SendStream::write_all(self, bytes)
            .await
            .map_err(|_| ())
    }
    fn finish(&mut self) {
        let _ = quinn::SendStream::finish(self);
    }
    async fn stopped(&mut self) {
        let _ = quinn::SendStream::stopped(self).await;
    }
}

impl LinkRecv for quinn::RecvStream {
    async fn read(&mut self, buf: &mut [u8]) -> Read {
        match quinn::RecvStream::read(self, buf).await {
            Ok(Some(n)) => Read::Data(n),
            Ok(None) => Read::Finished,
            Err(quinn::ReadError::Reset(_)) => Read::Reset,
            Err(_) => Read::Lost,
        }
    }
}

impl Link for quinn::Connection {
    type Send = quinn::SendStream;
    type Recv = quinn::RecvStream;
    async fn accept_bi(&self) -> Result<(Self::Send, Self::Recv), String> {
        quinn::Connection::accept_bi(self)
            .await
            .map_err(|e| e.to_string())
    }
    async fn any_stream(&self) {
        tokio::select! {
            _ = quinn::Connection::accept_uni(self) => {}
            _ = quinn::Connection::accept_bi(self) => {}
        }
    }
    async fn open_uni(&self) -> Result<Self::Send, ()> {
        quinn::Connection::open_uni(self).await.map_err(|_| ())
    }
    fn close(&self, code: u32, reason: &[u8]) {
        quinn::Connection::close(self, quinn::VarInt::from_u32(code), reason);
    }
    async fn closed(&self) {
        quinn::Connection::closed(self).await;
    }
    fn remote_address(&self) -> SocketAddr {
        quinn::Connection::remote_address(self)
    }
    fn udp_sent(&self) -> u64 {
        self.stats().udp_tx.bytes
    }
    const BINDING: Binding = Binding::Native;
}

#[cfg(feature = "web")]
mod web {
    use super::*;
    use web_transport_quinn as wt;

    impl LinkSend for wt::SendStream {
        async fn write_all(&mut self, bytes: &[u8]) -> Result<(), ()> {
            wt::SendStream::write_all(self, bytes).await.map_err(|_| ())
        }
        fn finish(&mut self) {
            let _ = wt::SendStream::finish(self);
        }
        async fn stopped(&mut self) {
            let _ = wt::SendStream::stopped(self).await;
        }
    }

    impl LinkRecv for wt::RecvStream {
        async fn read(&mut self, buf: &mut [u8]) -> Read {
            match wt::RecvStream::read(self, buf).await {
                Ok(Some(n)) => Read::Data(n),
                Ok(None) => Read::Finished,
                Err(wt::ReadError::Reset(_) | wt::ReadError::InvalidReset(_)) => Read::Reset,
                Err(_) => Read::Lost,
            }
        }
    }

    /// A WebTransport session (spec/session.md 9): closing it sends the
    /// `CLOSE_WEBTRANSPORT_SESSION` capsule with the code, so a browser's
    /// `WebTransport.closed` reports the code of section 7 itself.
    impl Link for wt::Session {
        type Send = wt::SendStream;
        type Recv = wt::RecvStream;
        async fn accept_bi(&self) -> Result<(Self::Send, Self::Recv), String> {
            wt::Session::accept_bi(self)
                .await
                .map_err(|e| e.to_string())
        }
        async fn any_stream(&self) {
            tokio::select! {
                _ = wt::Session::accept_uni(self) => {}
                _ = wt::Session::accept_bi(self) => {}
            }
        }
        async fn open_uni(&self) -> Result<Self::Send, ()> {
            wt::Session::open_uni(self).await.map_err(|_| ())
        }
        fn close(&self, code: u32, reason: &[u8]) {
            wt::Session::close(self, code, reason);
        }
        async fn closed(&self) {
            wt::Session::closed(self).await;
        }
        fn remote_address(&self) -> SocketAddr {
            quinn::Connection::remote_address(self)
        }
        fn udp_sent(&self) -> u64 {
            quinn::Connection::stats(self).udp_tx.bytes
        }
        const BINDING: Binding = Binding::WebTransport;
    }
}
