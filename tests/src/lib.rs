//! # psao-tests
//!
//! The shared test kit of the psao workspace and, in `tests/`, the tests
//! that cross crates (modelled on rustls's `rustls-test`):
//!
//! - [`relay`]: a lossy, reordering UDP relay for QUIC over loopback;
//! - [`scenes`]: small scenes where something changes every frame;
//! - [`sim`]: a simulated link on a virtual clock (latency, jitter, loss,
//!   bandwidth), seeded, for driving the sans-IO cores without sockets;
//!
//! Nothing here ships in a library crate's public API.

pub mod relay;
pub mod scenes;
pub mod sim;
