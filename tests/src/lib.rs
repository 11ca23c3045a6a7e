//! # psao-tests
//!
//! The shared test kit of the psao workspace and, in `tests/`, the tests
//! that cross crates (modelled on rustls's `rustls-test`):
//!
//! - [`raw`]: messages and frames built byte by byte from
//!   spec/wire-format.md, not with psao-codec's writer;
//! - [`synthetic`]: a synthetic server stream (a floor, a wall, a sliding
//!   box, drifting AO) for the codec's benches and examples;
//! - [`sim`]: a simulated link on a virtual clock (latency, jitter, loss,
//!   bandwidth), seeded, for driving the sans-IO cores without sockets;
//! - `scenes` (feature `scenes`): small scenes where something changes
//!   every frame, pipelines over them, their points in world space;
//! - `relay` (feature `relay`): a lossy, reordering UDP relay for QUIC
//!   over loopback;
//! - `moq_relay` (feature `moq-relay`): the real `moq-relay` as a process on loopback (one,
//!   or two clustered), for the MoQ tests.
//!
//! Without default features only psao-codec comes with it, so the codec's
//! own tests use it without building the rest of the workspace. Nothing
//! here ships in a library crate's public API.

#[cfg(feature = "moq-relay")]
pub mod moq_relay;
pub mod raw;
pub mod reference;
#[cfg(feature = "relay")]
pub mod relay;
#[cfg(feature = "scenes")]
pub mod scenes;
pub mod sim;
pub mod synthetic;
