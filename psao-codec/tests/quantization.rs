//! Quantization error bounds stated in spec/wire-format.md.

use glam::{UVec3, Vec3};
use proptest::prelude::*;
use psao_codec::wire::point::*;

fn unit(v: [f32; 3]) -> Option<Vec3> {
    let v = Vec3::from(v);
    (v.length() > 1e-3).then(|| v.normalize())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn position_within_half_a_quantum(f in prop::array::uniform3(0.0f32..=1.0)) {
        let frac = Vec3::from(f);
        let q = quantize_position(frac);
        prop_assert!(q.max_element() < 32);
        let err = (dequantize_position(q) - frac).abs().max_element();
        prop_assert!(err <= 0.5 / 32.0 + 1e-6, "error {err} above half a quantum");
    }

    #[test]
    fn ao_within_1_over_510(ao in 0.0f32..=1.0) {
        let err = (dequantize_ao(quantize_ao(ao)) - ao).abs();
        prop_assert!(err <= 1.0 / 510.0 + 1e-7, "error {err}");
    }

    #[test]
    fn normal_within_stated_angle(v in prop::array::uniform3(-1.0f32..=1.0)) {
        if let Some(n) = unit(v) {
            let code = encode_normal(n);
            prop_assert!(code & 0x0F <= 14 && code >> 4 <= 14);
            let angle = decode_normal(code).dot(n).clamp(-1.0, 1.0).acos().to_degrees();
            prop_assert!(angle <= NORMAL_MAX_ERROR_DEGREES, "{n:?}: {angle} deg");
        }
    }

    #[test]
    fn word_roundtrip(p in prop::array::uniform3(0u32..32), nu in 0u8..15, nv in 0u8..15, ao in any::<u8>()) {
        let fields = PointFields { position: UVec3::from(p), normal: nu | nv << 4, ao };
        let w = PointWord::pack(fields);
        prop_assert!(w.is_allocated() && w.is_valid());
        prop_assert_eq!(w.fields(), fields);
        prop_assert_eq!(w.with_ao(ao.wrapping_add(1)).fields().ao, ao.wrapping_add(1));
    }
}

#[test]
fn ao_exhaustive_levels_roundtrip() {
    for q in 0..=255u8 {
        assert_eq!(quantize_ao(dequantize_ao(q)), q);
    }
    assert_eq!(quantize_ao(f32::NAN), 0);
    assert_eq!(quantize_ao(-3.0), 0);
    assert_eq!(quantize_ao(7.0), 255);
}

#[test]
fn axis_normals_are_exact() {
    for n in [
        Vec3::X,
        Vec3::NEG_X,
        Vec3::Y,
        Vec3::NEG_Y,
        Vec3::Z,
        Vec3::NEG_Z,
    ] {
        let d = decode_normal(encode_normal(n));
        assert!((d - n).length() < 1e-6, "{n:?} decodes to {d:?}");
    }
}

#[test]
fn degenerate_normals_encode_as_plus_z() {
    for n in [Vec3::ZERO, Vec3::NAN, Vec3::new(f32::INFINITY, 0.0, 0.0)] {
        assert_eq!(decode_normal(encode_normal(n)), Vec3::Z);
    }
}

#[test]
fn word_validity_rules() {
    assert!(PointWord::EMPTY.is_valid());
    // Unallocated but not zero.
    assert!(!PointWord(0x0000_0001).is_valid());
    // Allocated with normal nibble 15 (u or v).
    assert!(!PointWord(ALLOC_BIT | 0x0F00).is_valid());
    assert!(!PointWord(ALLOC_BIT | 0xF000).is_valid());
    assert!(PointWord(ALLOC_BIT | 0xEE00).is_valid());
}

#[test]
fn bit_layout_matches_spec() {
    let w = PointWord::pack(PointFields {
        position: UVec3::new(1, 2, 3),
        normal: 0x5A & 0xEE,
        ao: 0xC3,
    });
    assert_eq!(
        w.0,
        (1 << 31) | (3 << 26) | (2 << 21) | (1 << 16) | (0x4A << 8) | 0xC3
    );
}

#[test]
fn dense_sphere_respects_bound() {
    // Fibonacci sphere, 200k points: the worst case sits at the lower
    // hemisphere's diagonals.
    let n = 200_000;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut worst = 0f32;
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f32;
        let v = Vec3::new(r * phi.cos(), r * phi.sin(), z);
        let a = decode_normal(encode_normal(v))
            .dot(v)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        worst = worst.max(a);
    }
    assert!(worst <= NORMAL_MAX_ERROR_DEGREES, "worst {worst}");
    assert!(
        worst > NORMAL_MAX_ERROR_DEGREES - 1.0,
        "bound is loose: worst {worst}"
    );
}
