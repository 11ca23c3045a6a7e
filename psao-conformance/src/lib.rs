//! A conformance kit for the PSAO session protocol (spec/session.md), in
//! the spirit of h2spec (HTTP/2) and the Autobahn suite (WebSocket).
//!
//! [`server_cases::run`] connects to a server under test as a series of
//! bare QUIC clients, one per case, each taking one path of the spec: the
//! handshake and its variants, every class of malformed or oversized
//! uplink message, the uplink rate limit, keyframe requests of every
//! reason, moves, cameras, digests and closing. Each case has an id tied
//! to a spec section and passes, fails (with what was seen instead) or is
//! skipped (the server chose an option the case needs not). A [`Report`]
//! prints a line per case and the summary `N passed, N failed, N
//! skipped`, and writes JSON or JUnit XML for CI.
//!
//! [`client_cases::run`] is the other direction: a scripted server that
//! takes one client under test through a late join, a gap, a corrupt
//! frame, a resynchronization with `NOTICE` 2, every `NOTICE` code, a
//! wrong `DIGEST` and shutdown, checking what the client sends back.
//!
//! `psao conformance client --connect ADDR --fingerprint HEX` and `psao
//! conformance server --bind ADDR` run them from the command line.

pub mod client_cases;
pub mod probe;
pub mod report;
pub mod server_cases;

pub use report::{CaseResult, Outcome, Report};
