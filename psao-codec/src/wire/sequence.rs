//! Sequence number arithmetic (RFC 1982 serial numbers on 32 bits).

/// Whether `a` is newer than `b`: `0 < (a - b) mod 2^32 < 2^31`.
///
/// Sequences exactly 2^31 apart are not comparable; both directions answer
/// `false`, and decoders treat such a frame as out of sync.
pub fn is_newer(a: u32, b: u32) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < (1 << 31)
}
