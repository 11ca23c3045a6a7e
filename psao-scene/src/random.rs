//! Counter-based random numbers: a value depends only on (seed, stream,
//! index), so parallel work is deterministic whatever the thread count.

/// PCG-style 32-bit hash (one round of the PCG output permutation).
#[inline]
pub fn hash(mut x: u32) -> u32 {
    x = x.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let w = ((x >> ((x >> 28) + 4)) ^ x).wrapping_mul(277_803_737);
    (w >> 22) ^ w
}

/// A uniform number in `[0, 1)` for `(seed, stream, index)`.
#[inline]
pub fn uniform(seed: u64, stream: u32, index: u32) -> f32 {
    let s = hash(seed as u32 ^ hash((seed >> 32) as u32));
    let h = hash(s ^ hash(stream ^ hash(index)));
    (h >> 8) as f32 / (1u32 << 24) as f32
}
