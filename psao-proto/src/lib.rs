//! # psao-proto
//!
//! The PSAO session protocol (spec/session.md): a sans-IO core, and the
//! reference QUIC server and client on top of it.
//!
//! The sans-IO core (always built; bytes and `now` in, events and bytes
//! out, no sockets and no clock of its own):
//! - [`control`]: control messages and their byte layouts;
//!   [`records`]: frame records on the frame stream;
//! - [`ServerConn`] (negotiation, handshake deadline, uplink rate) and
//!   [`Outbox`] (a client's bounded frame queue, falling behind and
//!   resynchronizing with a keyframe) and [`Fanout`] (every client's
//!   outbox, one keyframe per state shared by all who ask, notices,
//!   views) and [`rate::RateWatch`] (whether the server keeps its
//!   announced frame rate) and [`OwnMirror`] (the server's mirror of
//!   its own stream, for digests): the server's session logic;
//! - [`ClientSession`]: the client's session logic around a
//!   [`psao_codec::Decoder`];
//! - [`FrameSource`]: what a server streams (a scene that steps and
//!   encodes frames);
//! - [`capture`]: capture files of received frames (spec/capture.md).
//!
//! The I/O (feature `quic`): [`serve()`] and [`connect()`] over quinn and
//! tokio, with TLS from [`tls`] (certificate files, or a self-signed
//! certificate whose fingerprint clients pin).
//!
//! ## Feature flags
//! - `quic` (default): the reference QUIC server and client. Without it
//!   (`default-features = false`) only the sans-IO core builds, on
//!   psao-codec, bytes, glam and thiserror.
//! - `zstd`, `lz4` (default): the codec's compressions, which a client
//!   decodes and offers in `HELLO`; `zstd-pure` decodes zstd in pure Rust
//!   instead, so that the session core builds for `wasm32-unknown-unknown`
//!   (`--no-default-features --features lz4,zstd-pure`: a browser
//!   client's core).
//! - `scene`: psao-scene's `Pipeline` implements [`FrameSource`], so
//!   `serve(Pipeline::new(scene, config)?, ...)` streams a scene.
//!
//! The `psao` command line is the `psao-cli` crate.

pub mod capture;
pub mod client;
pub mod codes;
#[cfg(feature = "quic")]
pub mod connect;
pub mod control;
pub mod fanout;
#[cfg(feature = "quic")]
mod link;
pub mod outbox;
pub mod own_mirror;
pub mod rate;
pub mod records;
#[cfg(feature = "scene")]
pub mod scene_source;
#[cfg(feature = "quic")]
pub mod server;
pub mod server_conn;
pub mod source;
#[cfg(feature = "quic")]
pub mod tls;
#[cfg(feature = "web")]
pub mod web;

pub use client::{
    CLOSE_AFTER_FRAMES, ClientConfig, ClientEvent, ClientSession, ClientStats,
    MAX_FAILED_KEYFRAMES, REQUEST_RETRY,
};
pub use codes::{Close, CloseCode, SessionError};
#[cfg(feature = "quic")]
pub use connect::{ClientHandle, ConnectError, Ended, connect};
pub use fanout::{ClientId, Fanout, Keyframes, Transmit};
#[cfg(feature = "quic")]
pub use link::Binding;
pub use outbox::{Outbox, Pushed};
pub use own_mirror::{OwnFrameRefused, OwnMirror};
#[cfg(feature = "quic")]
pub use server::{ClientFigures, ServeError, ServerConfig, ServerHandle, ServerStats, serve};
pub use server_conn::{Offer, ServerConn, ServerEvent, negotiate};
pub use source::{ClientViews, FrameSource, SourceError, SourceInfo, StepReport};
#[cfg(feature = "quic")]
pub use tls::{Identity, Trust};
