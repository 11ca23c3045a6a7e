//! The optional test of spec/wire-format.md 7.3.1 against hand-built views:
//! a candidate hidden behind another surface that covers it and faces the
//! pixel is left out; in every other case the result is eq. 2-4's.

mod common;

use common::*;
use glam::{Mat4, Vec3, Vec4};
use proptest::prelude::*;
use psao_codec::*;

/// A 4x4 view looking straight down: world x in [-0.2, 0.2] maps to
/// columns 0..4, world z in [-0.2, 0.2] to rows 0..4 (as a WebGPU
/// orthographic projection: `c = (x / 0.2, -z / 0.2, 0, 1)`).
fn top_view() -> Mat4 {
    Mat4::from_cols(
        Vec4::new(5.0, 0.0, 0.0, 0.0),
        Vec4::ZERO,
        Vec4::new(0.0, -5.0, 0.0, 0.0),
        Vec4::new(0.0, 0.0, 0.0, 1.0),
    )
}

const SIDE: u32 = 4;
const PIXELS: usize = (SIDE * SIDE) as usize;

/// A floor of instance 1 at y = 0.3 (identity transform) with a dark point
/// at x = 0 (under a plate leaning over x < 0.05) and an open one at
/// x = 0.12, and the view's surfaces: every pixel sees `surface`.
struct Case {
    decoder: Decoder,
    dark: f32,
    open: f32,
}

/// Instance 1's table: a dark point (AO 0.1) at local (0, 0.3, 0) and an
/// open one (0.9) at (`open_x`, 0.3, 0), both facing +Y, changes taken.
fn two_points(def: InstanceDef, open_x: f32) -> GridTable {
    let mut t = GridTable::new(1, def, 4).unwrap();
    t.set_point(0, Vec3::new(0.0, 0.3, 0.0), Vec3::Y, 0.1)
        .unwrap();
    t.set_point(1, Vec3::new(open_x, 0.3, 0.0), Vec3::Y, 0.9)
        .unwrap();
    t.take_dirty();
    t
}

fn floor_with_two_points() -> Case {
    let def = small_def(); // r = 0.2, cells of 0.25 from (-1, 0, -1)
    let t = two_points(def, 0.12);
    let ao_of = |id| {
        let Placement::Stored { cell, slot } = t.placement(id) else {
            panic!("point {id} is stored")
        };
        PointWord(t.cell(cell)[slot as usize]).ao()
    };
    let (dark, open) = (ao_of(0), ao_of(1));
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut f = enc.keyframe();
    f.snapshot(&t).unwrap();
    f.transform(
        1,
        1,
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
    );
    let frame = f.finish().unwrap().unwrap();
    let mut decoder = Decoder::new(Limits::default());
    decoder.receive(&frame.bytes).unwrap();
    Case {
        decoder,
        dark,
        open,
    }
}

/// The pixel being shaded: on the floor at x = 0.1, between the points.
const X: Vec3 = Vec3::new(0.1, 0.3, 0.0);

/// A plate leaning at 45 degrees over x < 0.05, its foot on the floor at
/// x = 0.05, its normal facing up and towards +x.
fn plate() -> (Vec3, Vec3) {
    (
        Vec3::new(0.05, 0.3, 0.0),
        Vec3::new(1.0, 1.0, 0.0).normalize(),
    )
}

struct Surfaces {
    position: Vec<Vec3>,
    normal: Vec<Vec3>,
    instance: Vec<u32>,
}

fn every_pixel_sees(q: Vec3, m: Vec3, id: u32) -> Surfaces {
    Surfaces {
        position: vec![q; PIXELS],
        normal: vec![m; PIXELS],
        instance: vec![id; PIXELS],
    }
}

fn seen<'a>(s: &'a Surfaces, to_clip: Mat4) -> SeenSurfaces<'a> {
    SeenSurfaces::new(to_clip, SIDE, SIDE, &s.position, &s.normal, &s.instance).unwrap()
}

/// `reconstruct_ao_seen` at local `x` (the world point too: the transform
/// is the identity) with normal Y, with a fresh memo, then again with the
/// same memo (its second answer must be the first's).
fn ao_seen(m: &InstanceMirror, x: Vec3, s: &Surfaces, to_clip: Mat4) -> f32 {
    let view = seen(s, to_clip);
    let memo = HiddenMemo::new(m, 1, &view);
    let first = reconstruct_ao_seen(&memo, x, Vec3::Y, x);
    let again = reconstruct_ao_seen(&memo, x, Vec3::Y, x);
    assert_eq!(first.to_bits(), again.to_bits(), "the memo changes nothing");
    first
}

#[test]
fn a_point_under_a_plate_that_faces_the_pixel_is_left_out() {
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    let plain = reconstruct_ao(m, X, Vec3::Y);
    // Both points weigh in eq. 2-4: the result lies strictly between.
    assert!(
        plain > case.dark + 0.05 && plain < case.open - 0.05,
        "{plain}"
    );
    let (q, n) = plate();
    let s = every_pixel_sees(q, n, 2);
    let got = ao_seen(m, X, &s, top_view());
    assert!(
        (got - case.open).abs() < 1e-6,
        "only the open point counts: {got}, its AO {}",
        case.open
    );
}

#[test]
fn where_nothing_is_hidden_the_result_is_eq_2_to_4_bit_for_bit() {
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    let plain = reconstruct_ao(m, X, Vec3::Y);
    let (q, n) = plate();
    let cases: Vec<(&str, Surfaces, Mat4)> = vec![
        (
            "nothing seen",
            every_pixel_sees(q, n, NO_SURFACE),
            top_view(),
        ),
        (
            "the candidate's own instance, facing within T_n of it (the plate as part of the floor's mesh)",
            every_pixel_sees(q, n, 1),
            top_view(),
        ),
        (
            "a wall that does not cover the candidate (N . m = 0)",
            every_pixel_sees(q, Vec3::X, 2),
            top_view(),
        ),
        (
            "a surface facing away from the candidate's side",
            every_pixel_sees(q, -n, 2),
            top_view(),
        ),
        (
            "points behind the camera (c.w < 0)",
            every_pixel_sees(q, n, 2),
            Mat4::from_cols(Vec4::X, Vec4::ZERO, Vec4::Y, Vec4::new(0.0, 0.0, 0.0, -1.0)),
        ),
        (
            "points projected outside the view",
            every_pixel_sees(q, n, 2),
            Mat4::from_cols(Vec4::X, Vec4::ZERO, Vec4::Y, Vec4::new(10.0, 0.0, 0.0, 1.0)),
        ),
        (
            "a NaN normal in the view",
            every_pixel_sees(q, Vec3::NAN, 2),
            top_view(),
        ),
    ];
    for (what, s, to_clip) in cases {
        let got = ao_seen(m, X, &s, to_clip);
        assert_eq!(
            got.to_bits(),
            plain.to_bits(),
            "{what}: {got} against {plain}"
        );
    }
    // A pixel behind the plate itself (under it, at x = 0.02) keeps both.
    let under = Vec3::new(0.02, 0.3, 0.0);
    let s = every_pixel_sees(q, n, 2);
    let got = ao_seen(m, under, &s, top_view());
    assert_eq!(got.to_bits(), reconstruct_ao(m, under, Vec3::Y).to_bits());
}

#[test]
fn a_surface_seen_at_one_of_the_four_pixels_around_the_candidate_is_enough() {
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    // The dark point projects to (u, v) = (2, 2): pixels 1 and 2 in each
    // direction surround it. Only pixel (2, 2) sees the plate.
    let (q, n) = plate();
    let mut s = every_pixel_sees(q, Vec3::Y, 1);
    let k = (2 * SIDE + 2) as usize;
    s.instance[k] = 2;
    s.normal[k] = n;
    let got = ao_seen(m, X, &s, top_view());
    assert!((got - case.open).abs() < 1e-6, "{got}");
    // Pixel (3, 3) does not surround it: nothing is hidden.
    let mut s = every_pixel_sees(q, Vec3::Y, 1);
    let k = (3 * SIDE + 3) as usize;
    s.instance[k] = 2;
    s.normal[k] = n;
    let got = ao_seen(m, X, &s, top_view());
    assert_eq!(got.to_bits(), reconstruct_ao(m, X, Vec3::Y).to_bits());
}

#[test]
fn a_point_in_bind_space_is_never_tested() {
    let def = InstanceDef {
        point_format: POINT_FORMAT_BIND32,
        ..small_def()
    };
    let t = two_points(def, 0.12);
    let mut decoder = Decoder::new(Limits::default());
    let mut enc = Encoder::new(EncoderConfig::default());
    decoder.receive(&keyframe(&mut enc, &[&t]).bytes).unwrap();
    let m = decoder.mirror().instance(1).unwrap();
    let (q, n) = plate();
    let s = every_pixel_sees(q, n, 2);
    let got = ao_seen(m, X, &s, top_view());
    assert_eq!(got.to_bits(), reconstruct_ao(m, X, Vec3::Y).to_bits());
}

#[test]
fn a_view_that_does_not_fit_its_surfaces_is_an_error_naming_what() {
    let s = every_pixel_sees(Vec3::ZERO, Vec3::Y, 0);
    let short = &s.position[..PIXELS - 1];
    assert_eq!(
        SeenSurfaces::new(top_view(), SIDE, SIDE, short, &s.normal, &s.instance).unwrap_err(),
        SeenSurfacesError::Length {
            what: "position",
            len: PIXELS - 1,
            pixels: PIXELS
        }
    );
    assert_eq!(
        SeenSurfaces::new(top_view(), 0, SIDE, &[], &[], &[]).unwrap_err(),
        SeenSurfacesError::Empty {
            width: 0,
            height: SIDE
        }
    );
    let nan = Mat4::from_cols(Vec4::NAN, Vec4::ZERO, Vec4::ZERO, Vec4::W);
    assert_eq!(
        SeenSurfaces::new(nan, SIDE, SIDE, &s.position, &s.normal, &s.instance).unwrap_err(),
        SeenSurfacesError::Matrix
    );
    let huge = SeenSurfaces::new(top_view(), u32::MAX, 2, &s.position, &s.normal, &s.instance);
    assert!(matches!(huge, Err(SeenSurfacesError::Length { .. })));
}

#[test]
fn the_pixel_grid_is_the_one_the_spec_gives() {
    // The dark point projects within 0.05 of (u, v) = (2, 2), so
    // i0 = floor(u - 0.5) = 1 and j0 = 1: pixels 1 and 2 in each direction
    // surround it, and no other. Only one pixel sees the plate each time.
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    let (q, n) = plate();
    for (i, j, hides) in [
        (1, 1, true),
        (2, 2, true),
        (1, 2, true),
        (2, 1, true),
        (0, 0, false),
        (3, 2, false),
        (2, 3, false),
    ] {
        let mut s = every_pixel_sees(q, Vec3::Y, 1);
        let k = (j * SIDE + i) as usize;
        s.instance[k] = 2;
        s.normal[k] = n;
        let got = ao_seen(m, X, &s, top_view());
        let hidden = (got - case.open).abs() < 1e-6;
        assert_eq!(hidden, hides, "pixel ({i}, {j}): {got}");
    }
}

#[test]
fn what_one_pixel_learns_about_a_point_does_not_decide_for_the_next() {
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    let (q, n) = plate();
    let s = every_pixel_sees(q, n, 2);
    let view = seen(&s, top_view());
    let memo = HiddenMemo::new(m, 1, &view);
    // First a pixel under the plate: it is behind the plate too, so the
    // dark point counts for it (condition (c) fails)...
    let under = Vec3::new(0.02, 0.3, 0.0);
    let got = reconstruct_ao_seen(&memo, under, Vec3::Y, under);
    assert_eq!(got.to_bits(), reconstruct_ao(m, under, Vec3::Y).to_bits());
    // ...then, with the same memo, the pixel in front of the foot: hidden.
    let got = reconstruct_ao_seen(&memo, X, Vec3::Y, X);
    assert!((got - case.open).abs() < 1e-6, "{got}");
}

#[test]
fn a_point_of_a_moved_and_scaled_instance_is_tested_where_the_transform_puts_it() {
    // The floor's instance moved by (0.5, 0, 0.2) and scaled by 2 in x; the
    // view and the plate moved with it, so the dark point is hidden as
    // before, in world space. Projecting the local point with the view's
    // matrix alone would put it outside the view.
    let def = small_def();
    let t = two_points(def, 0.06);
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut f = enc.keyframe();
    f.snapshot(&t).unwrap();
    let (sx, d) = (2.0, Vec3::new(0.5, 0.0, 0.2));
    f.transform(
        1,
        1,
        &[sx, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, d.x, d.y, d.z],
    );
    let mut decoder = Decoder::new(Limits::default());
    decoder
        .receive(&f.finish().unwrap().unwrap().bytes)
        .unwrap();
    let m = decoder.mirror().instance(1).unwrap();
    let to_clip = top_view() * Mat4::from_translation(-d);
    let (q, n) = plate();
    let s = every_pixel_sees(q + d, n, 2);
    let view = seen(&s, to_clip);
    let memo = HiddenMemo::new(m, 1, &view);
    assert!(memo.applies());
    // The pixel at local x = 0.05 is at world x = 0.6, in front of the foot
    // at world 0.55; the dark point at world 0.5 is behind the plate.
    let x = Vec3::new(0.05, 0.3, 0.0);
    let x_world = Vec3::new(0.5 + sx * 0.05, 0.3, 0.2);
    let plain = reconstruct_ao(m, x, Vec3::Y);
    let got = reconstruct_ao_seen(&memo, x, Vec3::Y, x_world);
    let open = {
        let Placement::Stored { cell, slot } = t.placement(1) else {
            panic!()
        };
        PointWord(t.cell(cell)[slot as usize]).ao()
    };
    assert!(
        plain < open - 0.05,
        "both points weigh without the test: {plain}"
    );
    assert!((got - open).abs() < 1e-6, "{got} against {open}");
}

#[test]
fn a_point_projected_in_the_last_half_pixel_tests_the_last_column_and_row() {
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    // The dark point at (u, v) = (3.8, 3.8): only pixel (3, 3) surrounds
    // it, clamped; the open point falls outside the view.
    let to_clip = Mat4::from_cols(
        Vec4::new(5.0, 0.0, 0.0, 0.0),
        Vec4::ZERO,
        Vec4::new(0.0, -5.0, 0.0, 0.0),
        Vec4::new(0.9, -0.9, 0.0, 1.0),
    );
    let (q, n) = plate();
    let mut s = every_pixel_sees(q, Vec3::Y, 1);
    let k = PIXELS - 1;
    s.instance[k] = 2;
    s.normal[k] = n;
    let got = ao_seen(m, X, &s, to_clip);
    assert!((got - case.open).abs() < 1e-6, "{got}");
}

/// Any float, NaN and the infinities included, often.
fn any_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -2.0f32..2.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(-f32::INFINITY),
        1 => Just(f32::MAX),
        1 => Just(0.0f32),
    ]
}

fn any_vec3() -> impl Strategy<Value = Vec3> {
    (any_f32(), any_f32(), any_f32()).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

proptest! {
    /// Whatever the view holds (NaNs, infinities, huge values, ids of any
    /// instance) and whatever its matrix (finite, as `SeenSurfaces::new`
    /// requires, but huge), the test never panics, and the result is a
    /// number in [0, 1] that equals eq. 2-4 or one of the point's AO
    /// values' weighted means (here: the open point's alone).
    #[test]
    fn odd_views_never_panic_and_give_ao_in_range(
        surfaces in proptest::collection::vec((any_vec3(), any_vec3(), 0u32..4), PIXELS),
        cols in proptest::collection::vec(prop_oneof![4 => -10.0f32..10.0, 1 => Just(f32::MAX), 1 => Just(-f32::MAX), 1 => Just(0.0f32)], 16),
        x in any_vec3(),
        x_world in any_vec3(),
    ) {
        let case = floor_with_two_points();
        let m = case.decoder.mirror().instance(1).unwrap();
        let s = Surfaces {
            position: surfaces.iter().map(|v| v.0).collect(),
            normal: surfaces.iter().map(|v| v.1).collect(),
            instance: surfaces.iter().map(|v| if v.2 == 3 { NO_SURFACE } else { v.2 }).collect(),
        };
        let to_clip = Mat4::from_cols_slice(&cols);
        let view = seen(&s, to_clip);
        let memo = HiddenMemo::new(m, 1, &view);
        for shaded in [x, X] {
            let got = reconstruct_ao_seen(&memo, shaded, Vec3::Y, x_world);
            prop_assert!((0.0..=1.0).contains(&got), "{got}");
            let plain = reconstruct_ao(m, shaded, Vec3::Y);
            prop_assert!(
                got == plain || (got - case.open).abs() < 1e-6 || (got - case.dark).abs() < 1e-6 || got == 1.0,
                "{got} against eq. 2-4's {plain}"
            );
        }
    }
}

#[test]
fn a_point_within_its_quantization_of_a_leaning_surface_counts_as_behind_it() {
    // With cells of 0.25 and r = 0.2: e = |cell_size| / 64 = 0.00677 and
    // r / 100 = 0.002. A point less than e - r / 100 in front of a surface
    // that leans over it may truly lie behind it by more than r / 100, and
    // is hidden; one farther in front is not. A surface parallel or
    // perpendicular to the point within the normal's quantization
    // (LEAN_MIN, LEAN_MAX) hides it only when it is behind by r / 100.
    let case = floor_with_two_points();
    let m = case.decoder.mirror().instance(1).unwrap();
    let def = m.def();
    let (e, h) = (def.cell_size.length() / 64.0, def.radius / 100.0);
    assert!(e > h, "{e} {h}");
    let mut dark = None;
    for_each_candidate(m, X, |p, _, ao| {
        if ao == case.dark {
            dark = Some(p);
        }
    });
    let dark = dark.expect("the dark point is a candidate at X");
    let plain = reconstruct_ao(m, X, Vec3::Y);
    // Every pixel sees a surface of normal `normal` through the point `d`
    // behind the decoded dark point (the point `d` in front of it); X
    // stays in front of it.
    let seen_through = |normal: Vec3, d: f32| {
        let s = every_pixel_sees(dark - d * normal, normal, 2);
        ao_seen(m, X, &s, top_view())
    };
    let (_, leaning) = plate();
    assert!(leaning.dot(Vec3::Y) > LEAN_MIN && leaning.dot(Vec3::Y) < LEAN_MAX);
    // Just inside and just outside e - r / 100 (a quarter of r / 100 off):
    // the r / 100 term counts as well as e.
    let near = seen_through(leaning, e - h - h / 4.0);
    assert!(
        (near - case.open).abs() < 1e-6,
        "{} in front of a leaning surface, within e - r / 100 = {}, is hidden: {near}",
        e - h - h / 4.0,
        e - h
    );
    let far = seen_through(leaning, e - h + h / 4.0);
    assert_eq!(
        far.to_bits(),
        plain.to_bits(),
        "{} in front, past e - r / 100 = {}, is not: {far} against {plain}",
        e - h + h / 4.0,
        e - h
    );
    // The band's edges: a surface at n_p . m = c, just inside and just
    // outside each bound, the point within e - r / 100 in front of it.
    let at = |c: f32| Vec3::new((1.0 - c * c).sqrt(), c, 0.0);
    for (c, leans) in [
        (LEAN_MIN - 0.01, false),
        (LEAN_MIN + 0.01, true),
        (LEAN_MAX - 0.005, true),
        (LEAN_MAX + 0.005, false),
    ] {
        let got = seen_through(at(c), 0.5 * (e - h));
        let want = if leans { case.open } else { plain };
        assert!(
            (got - want).abs() < 1e-6,
            "n_p . m = {c}: {got}, want {want} (leaning: {leans})"
        );
    }
    let upright = Vec3::new(1.0, 0.1, 0.0).normalize();
    assert!(upright.dot(Vec3::Y) > 0.0 && upright.dot(Vec3::Y) <= LEAN_MIN);
    for normal in [Vec3::Y, upright] {
        let got = seen_through(normal, 0.5 * (e - h));
        assert_eq!(
            got.to_bits(),
            plain.to_bits(),
            "a surface of normal {normal} does not lean over the point: {got} against {plain}"
        );
    }
    // ...while a point behind such a surface by more than r / 100 is.
    let behind = seen_through(upright, -2.0 * h);
    assert!(
        (behind - case.open).abs() < 1e-6,
        "a point 2 r / 100 behind a surface of normal {upright} is hidden: {behind}"
    );
}
