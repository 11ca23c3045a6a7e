//! CPU reconstruction (eq. 2-4) against hand-computed cases.

mod common;

use common::*;
use glam::{Affine3A, Quat, UVec3, Vec3};
use psao_codec::*;

/// A mirror of one table, through a real keyframe.
fn mirror_of(table: &mut GridTable) -> Decoder {
    table.take_dirty();
    let mut enc = Encoder::new(EncoderConfig::default());
    let mut d = Decoder::new(Limits::default());
    d.receive(&keyframe(&mut enc, &[table]).bytes).unwrap();
    d
}

/// Exact decoded position of a point as stored.
fn stored(table: &GridTable, id: u32, key_cell: UVec3) -> (Vec3, f32) {
    let Placement::Stored { cell, slot } = table.placement(id) else {
        panic!()
    };
    let def = table.def();
    let w = PointWord(table.cell(cell)[slot as usize]);
    (def.cell_min(key_cell) + w.frac() * def.cell_size, w.ao())
}

#[test]
fn no_points_gives_one() {
    let mut t = GridTable::new(1, small_def(), 4).unwrap();
    let d = mirror_of(&mut t);
    let m = d.mirror().instance(1).unwrap();
    assert_eq!(reconstruct_ao(m, Vec3::new(0.1, 0.5, 0.1), Vec3::Y), 1.0);
    assert_eq!(reconstruct_ao(m, Vec3::NAN, Vec3::Y), 1.0);
    assert_eq!(
        reconstruct_ao(m, Vec3::splat(1e30), Vec3::Y),
        1.0,
        "far outside the grid"
    );
}

#[test]
fn two_points_weighted_mean_matches_hand_computation() {
    let def = small_def(); // r = 0.2, cells 0.25
    let mut t = GridTable::new(1, def, 4).unwrap();
    let c = UVec3::new(4, 1, 4); // cell [0, 0.25) x [0.25, 0.5) x [0, 0.25)
    let p0 = def.cell_min(c) + Vec3::new(0.05, 0.1, 0.1);
    let p1 = def.cell_min(c) + Vec3::new(0.2, 0.1, 0.1);
    t.set_point(0, p0, Vec3::Y, 0.2).unwrap();
    t.set_point(1, p1, Vec3::Y, 0.8).unwrap();
    let (q0, ao0) = stored(&t, 0, c);
    let (q1, ao1) = stored(&t, 1, c);
    let d = mirror_of(&mut t);
    let m = d.mirror().instance(1).unwrap();
    let x = def.cell_min(c) + Vec3::new(0.1, 0.1, 0.1);
    let w0 = (0.2 - (q0 - x).length()) / 0.2;
    let w1 = (0.2 - (q1 - x).length()) / 0.2;
    assert!(w0 > 0.0 && w1 > 0.0);
    let expect = (w0 * ao0 + w1 * ao1) / (w0 + w1);
    let got = reconstruct_ao(m, x, Vec3::Y);
    assert!((got - expect).abs() < 1e-6, "{got} vs {expect}");
    // At a point exactly on a stored position, other points still count.
    let at = reconstruct_ao(m, q0, Vec3::Y);
    assert!(at < ao1 && at > ao0);
}

/// AO seen at `probe` (normal +Y) when a single point with AO 0 is stored
/// at `at` with normal `n`.
fn one_point_ao(at: Vec3, n: Vec3, probe: Vec3) -> f32 {
    let mut t = GridTable::new(1, small_def(), 4).unwrap();
    t.set_point(0, at, n, 0.0).unwrap();
    let d = mirror_of(&mut t);
    reconstruct_ao(d.mirror().instance(1).unwrap(), probe, Vec3::Y)
}

#[test]
fn normal_and_direction_tests_reject_points() {
    let def = small_def();
    let c = UVec3::new(4, 1, 4);
    let x = def.cell_min(c) + Vec3::splat(0.125);
    // A point facing away (n_p . n_x <= T_n).
    assert_eq!(one_point_ao(x + Vec3::X * 0.05, Vec3::NEG_Y, x), 1.0);
    // A point straight below along its normal ((n_p . dir)^2 >= T_d).
    assert_eq!(one_point_ao(x - Vec3::Y * 0.1, Vec3::Y, x), 1.0);
    // The same point beside x, in its tangent plane, counts.
    assert_eq!(one_point_ao(x + Vec3::X * 0.1, Vec3::Y, x), 0.0);
    // Beyond the radius (0.2) but within twice it, and nothing nearer:
    // the second pass (spec 7.3) finds it.
    assert_eq!(one_point_ao(x + Vec3::X * 0.21, Vec3::Y, x), 0.0);
    // Beyond twice the radius: no weight, open.
    assert_eq!(one_point_ao(x + Vec3::X * 0.41, Vec3::Y, x), 1.0);
    // Within quantization noise (|cell_size|/64 = 0.0068) the direction
    // test is skipped: a point just above x along its normal still counts.
    let mut t = GridTable::new(1, def, 4).unwrap();
    t.set_point(0, x, Vec3::Y, 0.0).unwrap();
    let (q, _) = stored(&t, 0, c);
    assert_eq!(one_point_ao(x, Vec3::Y, q - Vec3::Y * 0.004), 0.0);
    assert_eq!(one_point_ao(x, Vec3::Y, q - Vec3::Y * 0.01), 1.0);
}

#[test]
fn two_by_two_by_two_neighbourhood_reaches_across_cells() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 4).unwrap();
    let c = UVec3::new(4, 1, 4);
    // x in the upper half of cell c: the neighbourhood is c..c+1 per axis.
    let x = def.cell_min(c) + Vec3::splat(0.2);
    let across = def.cell_min(c + UVec3::ONE) + Vec3::splat(0.01);
    t.set_point(0, across, Vec3::Y, 0.0).unwrap();
    let d = mirror_of(&mut t);
    assert_eq!(base_cell(d.mirror().instance(1).unwrap(), x), c.as_ivec3());
    let ao = reconstruct_ao(
        d.mirror().instance(1).unwrap(),
        x,
        (Vec3::Y + Vec3::X * 0.3).normalize(),
    );
    assert_eq!(ao, 0.0);
    // From the lower half of c, cell c+1 is outside the 2x2x2 block.
    let low = def.cell_min(c) + Vec3::splat(0.1);
    assert_eq!(
        reconstruct_ao(d.mirror().instance(1).unwrap(), low, Vec3::Y),
        1.0
    );
}

#[test]
fn grid_border_cells_are_skipped_not_wrapped() {
    let def = small_def();
    let mut t = GridTable::new(1, def, 4).unwrap();
    // A point in cell x = 7 (last column); sample from just outside x = 0's side.
    t.set_point(
        0,
        def.cell_min(UVec3::new(7, 0, 0)) + Vec3::splat(0.1),
        Vec3::Y,
        0.0,
    )
    .unwrap();
    let d = mirror_of(&mut t);
    let m = d.mirror().instance(1).unwrap();
    assert_eq!(
        reconstruct_ao(m, def.origin + Vec3::new(-0.01, 0.1, 0.1), Vec3::Y),
        1.0
    );
    assert_eq!(
        reconstruct_ao(
            m,
            def.cell_min(UVec3::new(7, 0, 0)) + Vec3::new(0.25, 0.1, 0.1),
            Vec3::Y
        ),
        0.0
    );
}

#[test]
fn world_to_local_inverts_rigid_and_scaled_transforms() {
    let m = Affine3A::from_scale_rotation_translation(
        Vec3::new(2.0, 1.0, 0.5),
        Quat::from_rotation_y(0.7),
        Vec3::new(10.0, -3.0, 2.0),
    );
    let local = Vec3::new(0.3, 0.2, -0.1);
    let n_local = Vec3::new(0.0, 1.0, 1.0).normalize();
    let world = m.transform_point3(local);
    // World normal: inverse transpose of the linear part.
    let n_world = (m.matrix3.inverse().transpose() * n_local).normalize();
    let (x, n) = world_to_local(&m, world, n_world).unwrap();
    assert!((x - local).length() < 1e-5);
    assert!((n - n_local).length() < 1e-5);
    let singular = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    assert!(world_to_local(&singular, world, Vec3::Y).is_none());
}

/// A full cell's overflow chain counts in the weighted mean: three points
/// at one place in cells of one slot give the mean of all three with
/// chains, and the first alone without (the other two dropped).
#[test]
fn reconstruction_follows_overflow_chains() {
    for overflow in [true, false] {
        let def = InstanceDef {
            cell_capacity: 1,
            overflow,
            ..small_def()
        };
        let mut t = GridTable::new(1, def, 4).unwrap();
        let cell = UVec3::new(3, 1, 3);
        let at = def.cell_min(cell) + def.cell_size * 0.5;
        for (id, ao) in [(0, 0.0), (1, 0.4), (2, 1.0)] {
            t.set_point(id, at, Vec3::Y, ao).unwrap();
        }
        let d = mirror_of(&mut t);
        let m = d.mirror().instance(1).unwrap();
        let links: Vec<u32> = m.chain(def.key(cell)).collect();
        let ao = reconstruct_ao(m, at, Vec3::Y);
        if overflow {
            assert_eq!(links.len(), 3);
            let want = (0..3).map(|id| stored(&t, id, cell).1).sum::<f32>() / 3.0;
            assert!((ao - want).abs() < 1e-6, "{ao} vs {want}");
        } else {
            assert_eq!(links.len(), 1);
            assert_eq!(t.stats().dropped, 2);
            assert!((ao - stored(&t, 0, cell).1).abs() < 1e-6, "{ao}");
        }
    }
}

/// Eq. 2 with the rejections of eq. 3 as written (spec/wire-format.md
/// 7.3), with no shortcut: the normal test, the distance, the direction
/// test past the quantization noise.
fn weight_as_written(p: Vec3, n_p: Vec3, x: Vec3, n_x: Vec3, w: &WeightParams) -> f32 {
    let facing = n_p.dot(n_x);
    if facing.is_nan() || facing <= w.t_n {
        return 0.0;
    }
    let d = p - x;
    let dist = d.length();
    let a = (w.radius - dist) / w.radius;
    if a.is_nan() || a <= 0.0 {
        return 0.0;
    }
    if dist > w.noise {
        let c = n_p.dot(d) / dist;
        if c * c >= w.t_d {
            return 0.0;
        }
    }
    a
}

/// The candidates at `x` in the order of the reconstruction before its
/// lookups were split into phases (c9f68ab): cells `dz`, then `dy`, then
/// `dx` (fastest), each cell's chain from its key, each pool cell's
/// points in slot order; as bits.
fn candidates_in_the_first_order(inst: &InstanceMirror, x: Vec3) -> Vec<[u32; 7]> {
    let d = inst.def();
    let base = base_cell(inst, x);
    let mut out = Vec::new();
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let c = base + glam::IVec3::new(dx, dy, dz);
                if c.cmplt(glam::IVec3::ZERO).any() || c.cmpge(d.dims.as_ivec3()).any() {
                    continue;
                }
                let c = c.as_uvec3();
                let min = d.cell_min(c);
                for cell in inst.chain(d.key(c)) {
                    for w in inst.cell_points(cell) {
                        let p = min + w.frac() * d.cell_size;
                        out.push(bits(p, w.normal(), w.ao()));
                    }
                }
            }
        }
    }
    out
}

fn bits(p: Vec3, n: Vec3, ao: f32) -> [u32; 7] {
    [p.x, p.y, p.z, n.x, n.y, n.z, ao].map(f32::to_bits)
}

/// [`for_each_candidate`]'s candidates, as bits.
fn candidates(inst: &InstanceMirror, x: Vec3) -> Vec<[u32; 7]> {
    let mut out = Vec::new();
    for_each_candidate(inst, x, |p, n, ao| out.push(bits(p, n, ao)));
    out
}

/// Eq. 4 as the spec words it (7.3): the weighted mean at r over the 2x2x2
/// cells, and when no point has weight, the same cells again at 2r.
fn two_passes(inst: &InstanceMirror, x: Vec3, n: Vec3) -> f32 {
    let params = WeightParams::of(inst.def());
    for radius in [params.radius, 2.0 * params.radius] {
        let w = WeightParams { radius, ..params };
        let (mut sum_w, mut sum) = (0.0f32, 0.0f32);
        for_each_candidate(inst, x, |p, n_p, ao| {
            let a = weight_as_written(p, n_p, x, n, &w);
            assert_eq!(a.to_bits(), weight(p, n_p, x, n, &w).to_bits());
            sum_w += a;
            sum += a * ao;
        });
        if sum_w > 0.0 {
            return sum / sum_w;
        }
    }
    1.0
}

proptest::proptest! {
    /// The reconstruction (whose weight drops far points before the
    /// square root) is eq. 2-4 as written, bit for bit, at points near
    /// stored ones, in gaps, and far away.
    #[test]
    fn reconstruction_equals_the_equations_as_written_bit_for_bit(
        seed in 0u64..1_000_000,
        probes in proptest::collection::vec((-1.2f32..1.2, -1.2f32..1.2, -1.2f32..1.2, 0usize..6), 1..40),
    ) {
        let mut t = GridTable::new(1, small_def(), 400).unwrap();
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        for id in 0..300 {
            let p = Vec3::new(next() * 2.0 - 1.0, next() * 0.3 - 0.15, next() * 2.0 - 1.0);
            let n = Vec3::new(next() - 0.5, 1.0, next() - 0.5);
            t.set_point(id, p, n, next()).unwrap();
        }
        let d = mirror_of(&mut t);
        let inst = d.mirror().instance(1).unwrap();
        let normals = [Vec3::Y, -Vec3::Y, Vec3::X, Vec3::new(0.3, 0.9, 0.1).normalize(), Vec3::Z, Vec3::ZERO];
        for (x, y, z, k) in probes {
            let (x, n) = (Vec3::new(x, y * 0.2, z), normals[k]);
            proptest::prop_assert_eq!(candidates(inst, x), candidates_in_the_first_order(inst, x));
            proptest::prop_assert_eq!(
                reconstruct_ao(inst, x, n).to_bits(),
                two_passes(inst, x, n).to_bits()
            );
        }
    }
}

proptest::proptest! {
    /// The same with cells twice the radius wide (the server's layout),
    /// overflow chains, and the grid far from the origin: still eq. 2-4 as
    /// written, bit for bit.
    #[test]
    fn cells_two_radii_wide_far_from_the_origin_bit_for_bit(
        seed in 0u64..1_000_000,
        radius in 0.03f32..0.2,
        offset in proptest::sample::select(vec![0.0f32, 37.5, 1000.0, -65536.0, 3.0e5]),
        probes in proptest::collection::vec((-1.2f32..1.2, -1.2f32..1.2, -1.2f32..1.2, 0usize..6), 1..40),
    ) {
        let shift = Vec3::new(offset, -0.5 * offset, 0.25 * offset);
        let def = InstanceDef {
            origin: small_def().origin + shift,
            cell_size: Vec3::splat(2.0 * radius),
            dims: UVec3::new(
                (2.0 / (2.0 * radius)) as u32 + 1,
                (1.0 / (2.0 * radius)) as u32 + 1,
                (2.0 / (2.0 * radius)) as u32 + 1,
            ),
            table_log2: 8,
            cell_pool: 1024,
            overflow: true,
            radius,
            ..small_def()
        };
        let mut t = GridTable::new(1, def, 400).unwrap();
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        for id in 0..300 {
            let p = Vec3::new(next() * 2.0 - 1.0, next() * 0.3 - 0.15 + 0.5, next() * 2.0 - 1.0);
            let n = Vec3::new(next() - 0.5, 1.0, next() - 0.5);
            t.set_point(id, p + shift, n, next()).unwrap();
        }
        let d = mirror_of(&mut t);
        let inst = d.mirror().instance(1).unwrap();
        let normals = [Vec3::Y, -Vec3::Y, Vec3::X, Vec3::new(0.3, 0.9, 0.1).normalize(), Vec3::Z, Vec3::ZERO];
        for (x, y, z, k) in probes {
            let (x, n) = (Vec3::new(x, y * 0.2 + 0.5, z) + shift, normals[k]);
            proptest::prop_assert_eq!(candidates(inst, x), candidates_in_the_first_order(inst, x));
            proptest::prop_assert_eq!(
                reconstruct_ao(inst, x, n).to_bits(),
                two_passes(inst, x, n).to_bits()
            );
        }
    }
}
