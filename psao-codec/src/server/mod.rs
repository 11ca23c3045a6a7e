//! The server half: the authoritative per-instance hash grid with its
//! dirty set ([`GridTable`](crate::GridTable)), and the
//! [`Encoder`](crate::Encoder) that turns its changes into numbered frames.

pub(crate) mod encoder;
pub(crate) mod table;
