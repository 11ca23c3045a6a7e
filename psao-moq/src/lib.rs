//! # psao-moq
//!
//! PSAO frames as a Media over QUIC broadcast (spec/moq.md), so that
//! `moq-relay` fans one encoded stream out to any number of viewers: AO is
//! view-independent, and a group that opens with a keyframe and goes on
//! with deltas is a late join and a resync at once, with no per-viewer
//! state at the origin. Frames stay byte for byte those of
//! spec/wire-format.md; the codec's decoder and mirror are reused as they
//! are.
//!
//! The sans-IO core (always built, on psao-codec and psao-proto's core):
//! - [`catalog`]: the `catalog` track (a `WELCOME` body), the `digest`
//!   track's frames, track and broadcast names;
//! - [`Broadcaster`]: the publisher's plan: which frame goes into which
//!   group, when a group rolls over to a new keyframe, which digests go
//!   out;
//! - [`Follower`]: the subscriber's mirror: catalog checks, groups joined
//!   mid-way, lost or out of order, digests compared.
//!
//! The I/O (feature `net`, default): [`net::publish()`] and
//! [`net::subscribe()`] over moq-net 0.3.18 (pinned exactly) on
//! web-transport-quinn, quinn and tokio. Neither psao-codec nor the
//! session core of psao-proto depends on this crate.

pub mod broadcaster;
pub mod catalog;
pub mod follower;
#[cfg(feature = "net")]
pub mod net;

pub use broadcaster::{BroadcastStats, Broadcaster, GroupPolicy, Write};
pub use follower::{
    DigestCheck, FollowError, FollowStats, Followed, Follower, HELD_DIGESTS, MAX_FAILED_KEYFRAMES,
};
