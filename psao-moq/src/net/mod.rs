//! The I/O layer (feature `net`): a publisher and a subscriber that speak
//! moq-lite to `moq-relay` over raw QUIC, with moq-net on
//! web-transport-quinn (quinn 0.11 and tokio, the stack psao's own server
//! uses).
//!
//! - [`dial`]: a relay's URL and the QUIC connection to it;
//! - [`publish()`]: steps a [`psao_proto::FrameSource`] and publishes its
//!   broadcast (spec/moq.md), reconnecting when the relay goes away;
//! - [`subscribe()`]: follows a broadcast through a relay (or the next of
//!   several, when one fails) into a [`crate::Follower`];
//! - [`local_relay`]: `moq-relay` processes on loopback (a relay, or a
//!   cluster sharing one certificate) for demos, benchmarks and tests.

pub mod dial;
pub mod local_relay;
pub mod publish;
pub mod subscribe;

pub use dial::{MoqError, RelayUrl};
pub use local_relay::{LocalRelay, LocalRelayError, RelayCert, find_relay_binary};
pub use publish::{
    Link, PublishOptions, PublishStats, Publisher, Publishing, publish, publish_alongside,
};
pub use subscribe::{
    ANNOUNCE_TIMEOUT, MAX_CAPTURED, MAX_CAPTURED_BYTES, SubscribeOptions, SubscribeStats,
    Subscription, subscribe,
};
