//! # psao-proto
//!
//! The PSAO session protocol over QUIC (spec/session.md): a sans-IO core
//! and the reference server and client on top of it.
//!
//! - [`control`]: control messages and their byte layouts;
//!   [`records`]: frame records on the frame stream;
//! - [`ServerConn`] (negotiation, handshake deadline, uplink rate) and
//!   [`Outbox`] (a client's bounded frame queue, falling behind and
//!   resynchronizing with a keyframe): the server's session logic;
//! - [`ClientSession`]: the client's session logic around a
//!   [`psao_codec::Decoder`];
//! - [`serve()`] and [`connect()`]: the I/O (quinn and tokio), with TLS from
//!   [`tls`] (certificate files, or a self-signed certificate whose
//!   fingerprint clients pin);
//! - [`relay`]: a lossy, reordering UDP relay for testing over loopback;
//! - [`capture`]: capture files of received frames (spec/capture.md).
//!
//! The `psao` binary (`src/bin/psao.rs`) runs the demo, a server and a
//! viewer.

pub mod capture;
pub mod client;
pub mod codes;
pub mod connect;
pub mod control;
pub mod outbox;
pub mod records;
pub mod relay;
pub mod server;
pub mod server_conn;
pub mod tls;

pub use client::{
    ClientConfig, ClientEvent, ClientSession, ClientStats, MAX_FAILED_KEYFRAMES, REQUEST_RETRY,
};
pub use codes::{Close, CloseCode};
pub use connect::{ClientHandle, ConnectError, Ended, connect};
pub use outbox::{Outbox, Pushed};
pub use server::{ServeError, ServerConfig, ServerHandle, ServerStats, serve};
pub use server_conn::{Offer, ServerConn, ServerEvent, negotiate};
pub use tls::{Identity, Trust};
