//! The subcommands that talk QUIC or read captures, one module each, and
//! what they share ([`common`]).

pub mod common;
pub mod conformance;
pub mod demo;
pub mod demo_relay;
pub mod inspect;
pub mod record;
pub mod relay;
pub mod serve;
pub mod shots;
pub mod view;
pub mod web;
