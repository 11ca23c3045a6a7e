//! The packed 32-bit point word (spec/wire-format.md, section "Point word").
//!
//! ```text
//! bit 31      allocation flag (1 = a point lives in this slot)
//! bits 26..31 position z quantum (5 bits)
//! bits 21..26 position y quantum (5 bits)
//! bits 16..21 position x quantum (5 bits)
//! bits 12..16 octahedral normal v code (4 bits, 0..=14)
//! bits  8..12 octahedral normal u code (4 bits, 0..=14)
//! bits  0..8  ambient occlusion (8 bits, 0 = fully occluded, 255 = open)
//! ```
//!
//! An unallocated slot is the word `0`: every other unallocated value is invalid.

use glam::{UVec3, Vec3};

/// Number of quanta per cell axis for a point position (5 bits).
pub const POSITION_QUANTA: u32 = 32;
/// Number of levels per octahedral axis: codes `0..=14`, so that the six axis
/// directions are represented exactly. Code 15 is invalid on the wire.
pub const NORMAL_LEVELS: u32 = 15;
/// Largest angle, in degrees, between a unit normal and the decoded normal of
/// its code as chosen by [`encode_normal`]. Measured over 4 million normals
/// (`cargo run --release -p psao-codec --example normal_error`: 11.42 deg
/// worst, 5.67 deg mean), checked by `tests/quantization.rs`, stated in the
/// spec.
pub const NORMAL_MAX_ERROR_DEGREES: f32 = 11.6;

/// Allocation flag bit.
pub const ALLOC_BIT: u32 = 1 << 31;
/// Mask of the AO byte.
pub const AO_MASK: u32 = 0xFF;

/// A packed point word as stored in a cell and sent on the wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(transparent)]
pub struct PointWord(pub u32);

/// The fields of an allocated point word, still quantized.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PointFields {
    /// Position quanta inside the cell, each `0..32`.
    pub position: UVec3,
    /// Octahedral normal code: `u | v << 4`, each nibble `0..=14`.
    pub normal: u8,
    /// AO code, `0..=255` (255 = unoccluded).
    pub ao: u8,
}

impl PointWord {
    /// The empty (unallocated) slot.
    pub const EMPTY: PointWord = PointWord(0);

    /// Packs quantized fields into an allocated word. Components of
    /// `position` above 31 and normal nibbles above 14 are clamped.
    pub fn pack(fields: PointFields) -> PointWord {
        let p = fields.position.min(UVec3::splat(POSITION_QUANTA - 1));
        let nu = (fields.normal & 0x0F).min(14) as u32;
        let nv = (fields.normal >> 4).min(14) as u32;
        PointWord(
            ALLOC_BIT
                | (p.z << 26)
                | (p.y << 21)
                | (p.x << 16)
                | (nv << 12)
                | (nu << 8)
                | fields.ao as u32,
        )
    }

    /// Quantizes and packs a point. `frac` is the position inside its cell,
    /// each component in `[0, 1]`; `normal` need not be normalized; `ao` is
    /// clamped to `[0, 1]`.
    pub fn encode(frac: Vec3, normal: Vec3, ao: f32) -> PointWord {
        PointWord::pack(PointFields {
            position: quantize_position(frac),
            normal: encode_normal(normal),
            ao: quantize_ao(ao),
        })
    }

    /// Whether the allocation flag is set.
    pub fn is_allocated(self) -> bool {
        self.0 & ALLOC_BIT != 0
    }

    /// Whether the word is valid in a cell: `0`, or allocated with both
    /// normal nibbles at most 14.
    pub fn is_valid(self) -> bool {
        if !self.is_allocated() {
            return self.0 == 0;
        }
        let n = (self.0 >> 8) & 0xFF;
        (n & 0x0F) != 0x0F && (n >> 4) != 0x0F
    }

    /// The quantized fields (meaningful only for an allocated word).
    pub fn fields(self) -> PointFields {
        let w = self.0;
        PointFields {
            position: UVec3::new((w >> 16) & 31, (w >> 21) & 31, (w >> 26) & 31),
            normal: ((w >> 8) & 0xFF) as u8,
            ao: (w & AO_MASK) as u8,
        }
    }

    /// Position inside the cell, each component in `(0, 1)`: the centre of
    /// the quantum.
    pub fn frac(self) -> Vec3 {
        dequantize_position(self.fields().position)
    }

    /// Decoded unit normal (from [`normal_table`]).
    pub fn normal(self) -> Vec3 {
        normal_table()[((self.0 >> 8) & 0xFF) as usize]
    }

    /// Decoded AO in `[0, 1]`.
    pub fn ao(self) -> f32 {
        dequantize_ao((self.0 & AO_MASK) as u8)
    }

    /// The same word with its AO byte replaced.
    pub fn with_ao(self, ao: u8) -> PointWord {
        PointWord((self.0 & !AO_MASK) | ao as u32)
    }
}

/// `q = min(floor(f * 32), 31)` per axis, with `f` clamped to `[0, 1]`
/// (NaN maps to 0).
pub fn quantize_position(frac: Vec3) -> UVec3 {
    let q = |f: f32| {
        let f = if f.is_nan() { 0.0 } else { f.clamp(0.0, 1.0) };
        ((f * POSITION_QUANTA as f32) as u32).min(POSITION_QUANTA - 1)
    };
    UVec3::new(q(frac.x), q(frac.y), q(frac.z))
}

/// `(q + 0.5) / 32` per axis.
pub fn dequantize_position(q: UVec3) -> Vec3 {
    (q.as_vec3() + 0.5) / POSITION_QUANTA as f32
}

/// `round(clamp(ao, 0, 1) * 255)`, halves away from zero; NaN maps to 0.
pub fn quantize_ao(ao: f32) -> u8 {
    let ao = if ao.is_nan() { 0.0 } else { ao.clamp(0.0, 1.0) };
    (ao * 255.0).round() as u8
}

/// `q / 255`.
pub fn dequantize_ao(q: u8) -> f32 {
    q as f32 / 255.0
}

fn sign_not_zero(x: f32) -> f32 {
    if x < 0.0 { -1.0 } else { 1.0 }
}

/// Maps a direction to octahedral coordinates in `[-1, 1]^2`.
fn octahedral(n: Vec3) -> (f32, f32) {
    let s = n.x.abs() + n.y.abs() + n.z.abs();
    let (u, v) = (n.x / s, n.y / s);
    if n.z < 0.0 {
        (
            (1.0 - v.abs()) * sign_not_zero(u),
            (1.0 - u.abs()) * sign_not_zero(v),
        )
    } else {
        (u, v)
    }
}

/// Decodes an octahedral code `u | v << 4` to a unit vector (normative
/// mapping; nibbles above 14 are read as 14, though the wire forbids them).
pub fn decode_normal(code: u8) -> Vec3 {
    let qu = (code & 0x0F).min(14) as f32;
    let qv = (code >> 4).min(14) as f32;
    let mut u = qu / 7.0 - 1.0;
    let mut v = qv / 7.0 - 1.0;
    let z = 1.0 - u.abs() - v.abs();
    if z < 0.0 {
        let (ou, ov) = (u, v);
        u = (1.0 - ov.abs()) * sign_not_zero(ou);
        v = (1.0 - ou.abs()) * sign_not_zero(ov);
    }
    Vec3::new(u, v, z).normalize()
}

/// Decoded unit normals of all 256 normal codes (codes with a nibble of 15
/// decode as 14, like [`decode_normal`]).
pub fn normal_table() -> &'static [Vec3; 256] {
    static TABLE: std::sync::OnceLock<[Vec3; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|c| decode_normal(c as u8)))
}

/// Encodes a direction to the octahedral code whose decoded normal is
/// closest to it among the four codes around its octahedral coordinates.
/// A zero or non-finite vector encodes as +Z.
pub fn encode_normal(n: Vec3) -> u8 {
    if !n.is_finite() || n.length_squared() == 0.0 {
        return 7 | (7 << 4);
    }
    let n = n.normalize();
    let (u, v) = octahedral(n);
    let scale = (NORMAL_LEVELS - 1) as f32 / 2.0;
    let fu = ((u + 1.0) * scale).clamp(0.0, 14.0);
    let fv = ((v + 1.0) * scale).clamp(0.0, 14.0);
    let us = [fu.floor() as u8, fu.ceil() as u8];
    let vs = [fv.floor() as u8, fv.ceil() as u8];
    let mut best = (f32::NEG_INFINITY, 0u8);
    for u in us {
        for v in vs {
            let code = u | (v << 4);
            let d = decode_normal(code).dot(n);
            if d > best.0 {
                best = (d, code);
            }
        }
    }
    best.1
}
