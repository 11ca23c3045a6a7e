//! Point generation, elimination and grid layout.

use glam::{Affine3A, Vec3};
use psao_codec::{GridTable, InstanceDef, Placement};
use psao_scene::*;

fn nearest(points: &[Vec3]) -> Vec<f32> {
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            points
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, q)| p.distance(*q))
                .fold(f32::INFINITY, f32::min)
        })
        .collect()
}

fn plane() -> Mesh {
    Mesh::quad(Vec3::ZERO, Vec3::X * 4.0, Vec3::Y * 2.0)
}

#[test]
fn counts_positions_and_normals() {
    let m = plane();
    // Elimination's points alone (gap filling adds a few: below).
    let p = generate_points_with(&m, 100.0, 3, false).unwrap();
    assert_eq!(p.len(), 400, "8 m^2 x 100 spawned, half kept");
    assert!(p.positions.iter().all(|q| q.z == 0.0
        && q.x >= 0.0
        && q.x <= 4.0
        && q.y >= 0.0
        && q.y <= 2.0));
    assert!(p.normals.iter().all(|n| (*n - Vec3::Z).length() < 1e-6));
    // The interpolation radius is the Poisson disk radius 2 r_max.
    let r_max = (8.0f32 / (2.0 * 3f32.sqrt() * 400.0)).sqrt();
    assert!((p.radius - 2.0 * r_max).abs() < 1e-6);

    let mut two = plane();
    two.double_sided = true;
    let q = generate_points_with(&two, 100.0, 3, false).unwrap();
    assert_eq!(q.len(), 800);
    assert_eq!(q.normals.iter().filter(|n| n.z < 0.0).count(), 400);
}

#[test]
fn elimination_spreads_points_apart() {
    let m = plane();
    // Compare with an independent uniform set of the same size over the
    // same rectangle.
    let kept = generate_points_with(&m, 200.0, 11, false).unwrap();
    let uniform_set: Vec<Vec3> = (0..800u32)
        .map(|k| Vec3::new(uniform(99, 0, k) * 4.0, uniform(99, 1, k) * 2.0, 0.0))
        .collect();
    let half = &uniform_set[..kept.len()];
    let (nk, nu) = (nearest(&kept.positions), nearest(half));
    let min = |v: &[f32]| v.iter().copied().fold(f32::INFINITY, f32::min);
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(
        min(&nk) > 3.0 * min(&nu),
        "min NN {} vs {}",
        min(&nk),
        min(&nu)
    );
    assert!(
        mean(&nk) > 1.2 * mean(&nu),
        "mean NN {} vs {}",
        mean(&nk),
        mean(&nu)
    );
    // Fewer than 5% of the kept points have a neighbour closer than
    // 0.75 r_max (the radius is 2 r_max).
    let close = nk.iter().filter(|&&d| d < 0.375 * kept.radius).count();
    assert!(
        close * 20 < nk.len(),
        "{close} of {} closer than 0.75 r",
        nk.len()
    );
}

/// Nearest-neighbour distances through a grid of cell `cell` (at least
/// the largest distance of interest).
fn nearest_grid(points: &[Vec3], cell: f32) -> Vec<f32> {
    let key = |p: Vec3| (p / cell).floor().as_ivec3();
    let mut grid: std::collections::HashMap<glam::IVec3, Vec<usize>> = Default::default();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(i);
    }
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let c = key(*p);
            let mut best = f32::INFINITY;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    if let Some(l) = grid.get(&(c + glam::IVec3::new(dx, dy, 0))) {
                        for &j in l {
                            if j != i {
                                best = best.min(p.distance(points[j]));
                            }
                        }
                    }
                }
            }
            best
        })
        .collect()
}

#[test]
fn large_meshes_are_eliminated_in_tiles_as_evenly_as_small_ones() {
    // 8 m^2 at 75,000 per m^2: 600,000 spawned, in 10 tiles of 65,536
    // eliminated in parallel; the spread matches a small mesh's.
    let m = plane();
    let big = generate_points_with(&m, 75_000.0, 5, false).unwrap();
    assert_eq!(big.len(), 300_000);
    const { assert!(600_000 > 2 * TILE_POINTS, "the big mesh is tiled") };
    let small = generate_points_with(&m, 2_000.0, 5, false).unwrap();
    let share = |p: &PointSet| {
        let nn = nearest_grid(&p.positions, p.radius);
        let close = nn.iter().filter(|&&d| d < 0.375 * p.radius).count() as f64;
        let mean = nn.iter().map(|&d| d as f64).sum::<f64>() / nn.len() as f64;
        (close / nn.len() as f64, mean / p.radius as f64)
    };
    let ((close_big, mean_big), (close_small, mean_small)) = (share(&big), share(&small));
    assert!(
        close_big < 0.05,
        "{close_big} of the points closer than 0.75 r_max"
    );
    assert!(
        close_big < close_small + 0.01 && (mean_big - mean_small).abs() < 0.03,
        "tiled: {close_big} close, mean {mean_big}; whole: {close_small}, {mean_small}"
    );
    // Every region keeps its share: 16 strips across the tiles' seams
    // hold the same number of points within 5%.
    let mut strips = [0u32; 16];
    for p in &big.positions {
        strips[((p.x / 4.0 * 16.0) as usize).min(15)] += 1;
    }
    let expect = big.len() as f64 / 16.0;
    assert!(
        strips
            .iter()
            .all(|&c| (c as f64 - expect).abs() < 0.05 * expect),
        "{strips:?}"
    );
}

#[test]
fn generation_is_deterministic_and_checks_its_input() {
    let m = plane();
    assert_eq!(
        generate_points(&m, 50.0, 1).unwrap(),
        generate_points(&m, 50.0, 1).unwrap()
    );
    assert_ne!(
        generate_points(&m, 50.0, 1).unwrap(),
        generate_points(&m, 50.0, 2).unwrap()
    );
    for d in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(matches!(
            generate_points(&m, d, 1),
            Err(SceneError::Parameter {
                name: "density",
                ..
            })
        ));
    }
    let mut bad = plane();
    bad.indices.push(9);
    assert!(matches!(
        generate_points(&bad, 10.0, 1),
        Err(SceneError::IndexCount { .. })
    ));
    let mut bad = plane();
    bad.indices[1] = 40;
    assert!(matches!(
        generate_points(&bad, 10.0, 1),
        Err(SceneError::IndexOutOfRange { index: 40, .. })
    ));
    let mut bad = plane();
    bad.positions[0].x = f32::NAN;
    assert!(matches!(
        generate_points(&bad, 10.0, 1),
        Err(SceneError::NonFiniteVertex { vertex: 0, .. })
    ));
    // Zero-area geometry gives no points, not an error.
    let flat = Mesh {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        normals: vec![Vec3::Z; 3],
        indices: vec![0, 1, 2],
        ..Mesh::default()
    };
    assert!(generate_points(&flat, 10.0, 1).unwrap().is_empty());
    // A quad with parallel edges has no normal: refused, not NaN points.
    let degenerate = Mesh::quad(Vec3::ZERO, Vec3::X, Vec3::X);
    assert!(matches!(
        generate_points(&degenerate, 10.0, 1),
        Err(SceneError::NonFiniteVertex { .. })
    ));
}

#[test]
fn layout_holds_every_point_of_a_box() {
    let m = Mesh::cuboid(Vec3::new(-1.0, 0.0, -2.0), Vec3::new(1.0, 0.5, 2.0));
    let pts = generate_points(&m, 400.0, 5).unwrap();
    let def = layout(
        0,
        m.bounds().unwrap(),
        m.area(),
        pts.len(),
        pts.radius,
        &LayoutParams::default(),
    )
    .unwrap();
    assert!(def.cell_size.min_element() >= 2.0 * pts.radius);
    let mut table = GridTable::new(0, def, pts.len() as u32).unwrap();
    for (i, (p, n)) in pts.positions.iter().zip(&pts.normals).enumerate() {
        table.set_point(i as u32, *p, *n, 1.0).unwrap();
    }
    let s = table.stats();
    assert_eq!(s.out_of_grid, 0);
    assert_eq!(s.bucket_overflow + s.pool_exhausted, 0, "{s:?}");
    // Box edges and corners crowd cells: cells are at least twice the
    // interpolation radius (the Poisson disk radius, about the point
    // spacing), so a face crossing a cell puts about 4.6 points in it, and
    // edges and corners fill its 7 slots. Overflow chains (the default)
    // keep every point; without them a few are dropped (under 3%), counted.
    assert!(def.overflow);
    assert_eq!(s.dropped, 0, "{s:?}");
    assert!(matches!(table.placement(0), Placement::Stored { .. }));
    let flat = InstanceDef {
        overflow: false,
        ..def
    };
    let mut table = GridTable::new(0, flat, pts.len() as u32).unwrap();
    for (i, (p, n)) in pts.positions.iter().zip(&pts.normals).enumerate() {
        table.set_point(i as u32, *p, *n, 1.0).unwrap();
    }
    let s = table.stats();
    assert!(
        s.dropped > 0 && s.dropped as usize * 33 < pts.len(),
        "{s:?} of {}",
        pts.len()
    );
    assert_eq!(s.dropped as u64, s.cell_overflow);
}

/// A grid laid out for less area than the mesh has (as a folded mesh's
/// cells outnumber its area estimate's) fills its buckets and pool;
/// `fit_to_points` sizes both to the points' own cells, and every point
/// is stored.
#[test]
fn fit_to_points_grows_a_short_table_and_pool() {
    let m = Mesh::cuboid(Vec3::new(-1.0, 0.0, -2.0), Vec3::new(1.0, 0.5, 2.0));
    let pts = generate_points(&m, 400.0, 5).unwrap();
    let short = layout(
        0,
        m.bounds().unwrap(),
        m.area() / 40.0,
        pts.len() / 40,
        pts.radius,
        &LayoutParams::default(),
    )
    .unwrap();
    let fill = |def: InstanceDef| {
        let mut t = GridTable::new(0, def, pts.len() as u32).unwrap();
        for (i, (p, n)) in pts.positions.iter().zip(&pts.normals).enumerate() {
            t.set_point(i as u32, *p, *n, 1.0).unwrap();
        }
        t.stats()
    };
    let before = fill(short);
    assert!(before.dropped > 0, "{before:?}");
    let fitted = fit_to_points(short, &pts.positions);
    assert!(fitted.cell_pool > short.cell_pool && fitted.table_log2 >= short.table_log2);
    assert_eq!(
        (fitted.origin, fitted.cell_size, fitted.dims),
        (short.origin, short.cell_size, short.dims),
        "the grid itself is kept"
    );
    let after = fill(fitted);
    assert_eq!(after.dropped, 0, "{after:?}");
    // A grid already large enough is kept as it is.
    assert_eq!(
        fit_to_points(fitted, &pts.positions).cell_pool,
        fitted.cell_pool
    );
}

#[test]
fn scene_validation_names_the_problem() {
    let mut s = Scene::default();
    s.add(plane(), Affine3A::IDENTITY);
    assert!(s.validate().is_ok());
    s.instances.push(Instance {
        mesh: 5,
        transform: Affine3A::IDENTITY,
        node: None,
        skin: None,
    });
    assert_eq!(
        s.validate(),
        Err(SceneError::MeshOutOfRange {
            instance: 1,
            mesh: 5,
            meshes: 1
        })
    );
    s.instances[1] = Instance {
        mesh: 0,
        transform: Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0)),
        node: None,
        skin: None,
    };
    assert_eq!(s.validate(), Err(SceneError::BadTransform { instance: 1 }));
    let world = {
        let mut t = Scene::default();
        t.add(plane(), Affine3A::from_translation(Vec3::Z * 3.0));
        t.world_triangles().unwrap()
    };
    assert!(world.iter().flatten().all(|p| p.z == 3.0));
}

#[test]
fn subdivision_keeps_the_surface() {
    let m = Mesh::cuboid(Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0));
    let s = m.subdivided(2);
    assert_eq!(s.triangle_count(), m.triangle_count() * 16);
    assert!((s.area() - m.area()).abs() < 1e-4);
    assert_eq!(s.bounds(), m.bounds());
    assert!(s.validate(0).is_ok());
}

#[test]
fn isolated_points_are_kept_first() {
    // A tight cluster and one far point: elimination thins the cluster.
    let mut pts: Vec<Vec3> = (0..20)
        .map(|i| Vec3::new(i as f32 * 0.01, 0.0, 0.0))
        .collect();
    pts.push(Vec3::new(50.0, 0.0, 0.0));
    let nrm = vec![Vec3::Z; pts.len()];
    let (kept, _) = eliminate(&pts, &nrm, 10, 1.0);
    assert_eq!(kept.len(), 10);
    assert!(kept.contains(&20), "{kept:?}");
}

#[test]
fn opposite_faces_of_thin_geometry_do_not_thin_each_other() {
    // A 1 cm slab: top and bottom points are within the elimination reach
    // of each other but face away, so each face keeps its share.
    let slab = Mesh::cuboid(Vec3::ZERO, Vec3::new(2.0, 2.0, 0.01));
    let p = generate_points(&slab, 200.0, 4).unwrap();
    let top = p.normals.iter().filter(|n| n.z > 0.5).count();
    let bottom = p.normals.iter().filter(|n| n.z < -0.5).count();
    assert!(top.abs_diff(bottom) * 10 < top, "top {top} bottom {bottom}");
    // Each face is itself evenly spread.
    let tops: Vec<Vec3> = p
        .positions
        .iter()
        .zip(&p.normals)
        .filter(|(_, n)| n.z > 0.5)
        .map(|(q, _)| *q)
        .collect();
    let nn = nearest(&tops);
    let close = nn.iter().filter(|&&d| d < 0.5 * p.radius).count();
    assert!(close * 20 < nn.len(), "{close} of {}", nn.len());
}

#[test]
fn layout_checks_parameters_and_handles_flat_meshes() {
    let b = (Vec3::ZERO, Vec3::ONE);
    let bad = LayoutParams {
        bucket_capacity: 0,
        ..LayoutParams::default()
    };
    assert!(matches!(
        layout(0, b, 1.0, 10, 0.1, &bad),
        Err(SceneError::Parameter {
            name: "bucket_capacity",
            ..
        })
    ));
    assert!(matches!(
        layout(0, b, 1.0, 10, f32::NAN, &LayoutParams::default()),
        Err(SceneError::Parameter { name: "radius", .. })
    ));
    // Zero area (no points): a valid coarse grid, not an error.
    let def = layout(0, b, 0.0, 0, 0.1, &LayoutParams::default()).unwrap();
    assert!(def.validate().is_ok());
    // A huge flat instance gets cells coarse enough for 32-bit keys.
    let def = layout(
        0,
        (Vec3::ZERO, Vec3::new(1e5, 0.0, 1e5)),
        1e10,
        1 << 20,
        0.01,
        &LayoutParams::default(),
    )
    .unwrap();
    assert!(psao_codec::key_fits(def.dims));
}

#[test]
fn points_and_the_whole_setup_do_not_depend_on_the_thread_count() {
    let in_pool = |threads: usize, f: &(dyn Fn() -> Vec<u8> + Sync)| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(f)
    };
    // A mesh large enough for several spawning and neighbour chunks.
    let mesh = Mesh::quad(Vec3::ZERO, Vec3::Z * 30.0, Vec3::X * 30.0).subdivided(3);
    let points = || {
        let p = generate_points(&mesh, 80.0, 9).unwrap();
        assert!(p.len() > 30_000, "{}", p.len());
        format!("{:?}", (p.positions, p.normals, p.anchors, p.radius)).into_bytes()
    };
    assert_eq!(in_pool(1, &points), in_pool(2, &points));
    // The whole setup (points of every instance, layout, the first trace):
    // the same keyframe byte for byte.
    let keyframe = || {
        let mut p = Pipeline::new(
            hall(HallParams {
                props: 12,
                figures: 1,
            }),
            PipelineConfig::with_density_and_rays(1.0, 4),
        )
        .unwrap();
        p.keyframe().unwrap().bytes.to_vec()
    };
    assert_eq!(in_pool(1, &keyframe), in_pool(3, &keyframe));
}

/// Eq. 1's `key mod T` clusters on some grids whatever the load: a column
/// of a 32 x 32 x 139 grid reaches 1 bucket in 8 of a 2^13-bucket table,
/// and 139 cells overfill them. `fit_to_points` doubles the table until the
/// points' keys fit, and none is dropped.
#[test]
fn fit_to_points_doubles_a_table_whose_buckets_the_keys_overfill() {
    let def = InstanceDef {
        origin: Vec3::ZERO,
        cell_size: Vec3::ONE,
        dims: glam::UVec3::new(32, 32, 139),
        table_log2: 13,
        bucket_capacity: 8,
        cell_capacity: 7,
        cell_pool: 4096,
        point_format: 0,
        overflow: true,
        radius: 0.4,
        t_n: 0.1,
        t_d: 0.7,
    };
    let column: Vec<Vec3> = (0..139)
        .map(|z| Vec3::new(0.5, 0.5, z as f32 + 0.5))
        .collect();
    let fill = |def: InstanceDef| {
        let mut t = GridTable::new(0, def, column.len() as u32).unwrap();
        for (i, p) in column.iter().enumerate() {
            t.set_point(i as u32, *p, Vec3::Y, 1.0).unwrap();
        }
        t.stats()
    };
    assert!(fill(def).bucket_overflow > 0);
    let fitted = fit_to_points(def, &column);
    assert!(fitted.table_log2 > def.table_log2, "{fitted:?}");
    assert_eq!(fill(fitted).dropped, 0);
}

/// Share of `spots` (position, normal) with a point of `p` facing the same
/// side (dot > 0.1, the client's T_n) within `reach`.
fn covered_share(p: &PointSet, spots: &[(Vec3, Vec3)], reach: f32) -> f64 {
    let hit = spots
        .iter()
        .filter(|(x, n)| {
            p.positions
                .iter()
                .zip(&p.normals)
                .any(|(q, m)| q.distance(*x) < reach && m.dot(*n) > 0.1)
        })
        .count();
    hit as f64 / spots.len() as f64
}

/// Spots spread uniformly over the faces of an axis-aligned box, with the
/// faces' outward normals.
fn box_spots(min: Vec3, max: Vec3, count: u32) -> Vec<(Vec3, Vec3)> {
    let size = max - min;
    (0..count)
        .map(|k| {
            let (u, v) = (uniform(7, 0, k), uniform(7, 1, k));
            let axis = (k % 3) as usize;
            let side = (k / 3) % 2;
            let mut n = Vec3::ZERO;
            n[axis] = if side == 0 { -1.0 } else { 1.0 };
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let mut x = min;
            x[axis] = if side == 0 { min[axis] } else { max[axis] };
            x[a] += u * size[a];
            x[b] += v * size[b];
            (x, n)
        })
        .collect()
}

#[test]
fn gap_filling_covers_strips_thinner_than_the_spacing() {
    // A 2 m bar 1 cm thick: at 400 points/m^2 its long faces (2 dm^2
    // each) spawn about 8 points and keep 4, half a metre apart, while
    // the interpolation radius is under 8 cm.
    let (min, max) = (Vec3::ZERO, Vec3::new(2.0, 0.01, 0.01));
    let bar = Mesh::cuboid(min, max);
    let spots = box_spots(min, max, 3000);
    let filled = generate_points(&bar, 400.0, 5).unwrap();
    let bare = generate_points_with(&bar, 400.0, 5, false).unwrap();
    assert_eq!(filled.radius, bare.radius, "the same spacing");
    let r = filled.radius;
    let (f1, b1) = (
        covered_share(&filled, &spots, r),
        covered_share(&bare, &spots, r),
    );
    assert!(
        b1 < 0.5,
        "elimination alone covers {b1} of the bar within r"
    );
    assert!(f1 > 0.97, "filled covers {f1} within r");
    assert_eq!(covered_share(&filled, &spots, 2.0 * r), 1.0, "within 2r");
    // Every kept point of the bare set is kept, and the fill's points lie
    // on the bar with its faces' normals.
    assert!(filled.len() > bare.len());
    for (p, n) in filled.positions.iter().zip(&filled.normals) {
        assert!(p.cmpge(min - 1e-6).all() && p.cmple(max + 1e-6).all());
        assert!((n.length() - 1.0).abs() < 1e-5);
    }
    // Deterministic.
    assert_eq!(filled, generate_points(&bar, 400.0, 5).unwrap());
}

#[test]
fn gap_filling_adds_little_on_open_surfaces() {
    let m = plane().subdivided(2);
    let filled = generate_points(&m, 200.0, 11).unwrap();
    let bare = generate_points_with(&m, 200.0, 11, false).unwrap();
    assert_eq!(bare.len(), 800);
    let extra = filled.len() - bare.len();
    assert!(
        extra * 100 < bare.len() * 5,
        "{extra} points added to {}",
        bare.len()
    );
}

#[test]
fn a_mesh_smaller_than_two_points_still_gets_points() {
    // 1 cm^2 at 100 points/m^2: 0.01 points' worth of area.
    let tiny = Mesh::quad(Vec3::ZERO, Vec3::X * 0.01, Vec3::Y * 0.01);
    assert!(
        generate_points_with(&tiny, 100.0, 1, false)
            .unwrap()
            .is_empty()
    );
    let p = generate_points(&tiny, 100.0, 1).unwrap();
    assert!(
        p.len() >= MIN_SPAWNED / 2,
        "{} points on a mesh spawning {MIN_SPAWNED}",
        p.len()
    );
}
