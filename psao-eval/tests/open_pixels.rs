//! Why a pixel was left open: one hand-placed pixel per cause.

use glam::{Affine3A, UVec3, Vec3};
use psao_codec::*;
use psao_eval::*;

/// Cells of 0.25 m over [-1, 1] x [0, 1] x [-1, 1], r = 0.2, T_n = 0.1,
/// T_d = 0.7.
fn def() -> InstanceDef {
    InstanceDef {
        origin: Vec3::new(-1.0, 0.0, -1.0),
        cell_size: Vec3::splat(0.25),
        dims: UVec3::new(8, 4, 8),
        table_log2: 6,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 256,
        point_format: POINT_FORMAT_PACKED32,
        overflow: false,
        radius: 0.2,
        t_n: 0.1,
        t_d: 0.7,
    }
}

#[test]
fn each_open_pixel_gets_the_test_that_failed() {
    let a = Vec3::new(0.51, 0.26, 0.51); // AO 0.2, facing +Y
    let b = Vec3::new(-0.5, 0.6, -0.5); // AO 0.2, facing +Y
    let c = Vec3::new(0.0, 0.6, 0.0); // AO 1 (open), facing +Y
    let mut t = GridTable::new(1, def(), 8).unwrap();
    t.set_point(0, a, Vec3::Y, 0.2).unwrap();
    t.set_point(1, b, Vec3::Y, 0.2).unwrap();
    t.set_point(2, c, Vec3::Y, 1.0).unwrap();
    t.take_dirty();
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut f = enc.keyframe();
    f.snapshot(&t).unwrap();
    f.transform(1, 1, &Affine3A::IDENTITY.to_cols_array());
    let frame = f.finish().unwrap().unwrap();
    let mut d = Decoder::new(Limits::default());
    d.receive(&frame.bytes).unwrap();
    // (position, normal, instance) per pixel, one per cause in the order
    // of the tests, then a pixel that is not open.
    let pixels = [
        (Vec3::new(-0.9, 0.9, -0.9), Vec3::Y, 7), // instance unknown
        (Vec3::new(-0.9, 0.9, -0.9), Vec3::Y, 1), // no point in its cells
        (a + Vec3::new(0.02, 0.0, 0.0), -Vec3::Y, 1), // a faces away
        (Vec3::new(0.87, 0.49, 0.87), Vec3::Y, 1), // a is 0.56 away
        (b - Vec3::new(0.0, 0.1, 0.0), Vec3::Y, 1), // b is along the normal
        (c + Vec3::new(0.05, 0.0, 0.0), Vec3::Y, 1), // c weighed, and open
        (b + Vec3::new(0.05, 0.0, 0.0), Vec3::Y, 1), // b weighed: dark
    ];
    let n = pixels.len();
    let g = GBuffer {
        width: n as u32,
        height: 1,
        position: pixels.iter().map(|p| p.0).collect(),
        normal: pixels.iter().map(|p| p.1).collect(),
        bind_position: vec![Vec3::ZERO; n],
        bind_normal: vec![Vec3::ZERO; n],
        instance: pixels.iter().map(|p| p.2).collect(),
        depth: vec![1.0; n],
    };
    let img = psao_image(d.mirror(), &g).unwrap();
    assert_eq!(img.unknown, 1);
    assert!(img.ao[..6].iter().all(|&v| v >= SHOWN_OPEN), "{:?}", img.ao);
    assert!(img.ao[6] < 0.5, "{:?}", img.ao);
    let reference = vec![0.5f32; n];
    let r = open_reasons(d.mirror(), &g, &reference, &img.ao);
    let causes = r.causes();
    for (k, (name, cause)) in causes.iter().enumerate() {
        assert_eq!(cause.pixels, 1, "{name}: {r:?}");
        assert!(
            (cause.sse - (img.ao[k] as f64 - 0.5).powi(2)).abs() < 1e-9,
            "{name}"
        );
    }
    // A reference that is not dark counts nowhere.
    let bright = vec![0.95f32; n];
    assert_eq!(
        open_reasons(d.mirror(), &g, &bright, &img.ao),
        OpenReasons::default()
    );
    // Merging adds.
    let mut twice = r;
    twice.merge(&r);
    assert_eq!(twice.points_open.pixels, 2);
    assert_eq!(twice.direction.sse, 2.0 * r.direction.sse);
}
