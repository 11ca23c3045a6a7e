//! Alpha masks: no points in holes, and rays pass through holes.

use std::sync::Arc;

use glam::{Vec2, Vec3};
use psao_scene::*;

/// A 4 m square at height `y` facing down, masked by a checkerboard of
/// `cells` x `cells` squares (holes where `x + y` is odd), or uniformly
/// with `factor` alone when `cells` is 0.
fn masked_ceiling(y: f32, cells: u32, factor: f32) -> Mesh {
    let mut m = Mesh::quad(Vec3::new(-2.0, y, -2.0), Vec3::X * 4.0, Vec3::Z * 4.0);
    let texture = (cells > 0).then(|| AlphaTexture {
        uvs: m
            .positions
            .iter()
            .map(|p| Vec2::new(p.x + 2.0, p.z + 2.0) / 4.0)
            .collect(),
        width: cells,
        height: cells,
        alpha: (0..cells * cells)
            .map(|i| {
                if (i % cells + i / cells).is_multiple_of(2) {
                    255
                } else {
                    0
                }
            })
            .collect(),
    });
    m.alpha = Some(AlphaMask {
        cutoff: 0.5,
        factor,
        vertex_alpha: Vec::new(),
        texture,
    });
    m
}

/// A mesh's triangles with their alpha masks, for a BVH.
fn geometry(mesh: &Mesh) -> Geometry {
    let mut g = Geometry::default();
    let mask = mesh.alpha.clone().map(Arc::new);
    for t in 0..mesh.triangle_count() {
        g.triangles.push(mesh.triangle(t));
        let i = &mesh.indices[3 * t..3 * t + 3];
        g.masks
            .push(mask.as_ref().map(|m| (m.clone(), [i[0], i[1], i[2]])));
    }
    g
}

#[test]
fn textures_sample_nearest_with_repeat() {
    let t = AlphaTexture {
        uvs: Vec::new(),
        width: 2,
        height: 1,
        alpha: vec![0, 255],
    };
    assert_eq!(t.sample(Vec2::new(0.25, 0.5)), 0.0);
    assert_eq!(t.sample(Vec2::new(0.75, 0.5)), 1.0);
    assert_eq!(t.sample(Vec2::new(1.25, 7.0)), 0.0, "repeats");
    assert_eq!(t.sample(Vec2::new(-0.25, 0.0)), 1.0, "repeats below 0");
    assert_eq!(t.sample(Vec2::NAN), 1.0, "no texel: solid");
}

#[test]
fn masks_are_checked_against_the_mesh() {
    let mut m = masked_ceiling(1.0, 4, 1.0);
    assert!(m.validate(0).is_ok());
    m.alpha.as_mut().unwrap().vertex_alpha = vec![1.0; 3];
    let e = m.validate(2).unwrap_err();
    assert!(e.to_string().contains("mesh 2 alpha mask"), "{e}");
    let mut m = masked_ceiling(1.0, 4, 1.0);
    m.alpha
        .as_mut()
        .unwrap()
        .texture
        .as_mut()
        .unwrap()
        .alpha
        .pop();
    assert!(m.validate(0).is_err());
    let mut m = masked_ceiling(1.0, 4, 1.0);
    m.alpha.as_mut().unwrap().cutoff = f32::NAN;
    assert!(m.validate(0).is_err());
}

#[test]
fn no_point_is_spawned_in_a_hole() {
    let solid = generate_points(&masked_ceiling(1.0, 0, 1.0), 200.0, 5).unwrap();
    let checker = masked_ceiling(1.0, 8, 1.0);
    let half = generate_points(&checker, 200.0, 5).unwrap();
    let none = generate_points(&masked_ceiling(1.0, 0, 0.2), 200.0, 5).unwrap();
    assert!(
        none.is_empty(),
        "a fully transparent surface holds no point"
    );
    // Half the area is holes: about half the points, each on a solid square.
    let ratio = half.len() as f32 / solid.len() as f32;
    assert!((0.45..0.55).contains(&ratio), "{ratio}");
    for (k, a) in half.anchors.iter().enumerate() {
        assert!(checker.solid(a.triangle as usize, a.weights), "point {k}");
        let p = half.positions[k];
        let (cx, cz) = (((p.x + 2.0) * 2.0) as u32, ((p.z + 2.0) * 2.0) as u32);
        assert_eq!((cx + cz) % 2, 0, "point {k} at {p} is in a hole");
    }
    // The solid parts keep the density of an unmasked surface, so the
    // Poisson radius is the same (computed over the solid area, not the
    // whole).
    assert!(
        (half.radius / solid.radius - 1.0).abs() < 0.05,
        "{} vs {}",
        half.radius,
        solid.radius
    );
}

#[test]
fn rays_pass_through_holes() {
    let params = AoParams {
        radius: 2.0,
        rays: 512,
        ..AoParams::default()
    };
    let ao_under = |ceiling: Mesh| {
        let bvh = Arc::new(TriangleBvh::new(geometry(&ceiling)));
        let tracer = AoTracer::from_layers(vec![Layer::world(bvh)]);
        tracer.trace(&[Vec3::ZERO], &[Vec3::Y], &params).unwrap().ao[0]
    };
    let solid = ao_under(masked_ceiling(0.5, 0, 1.0));
    let open = ao_under(masked_ceiling(0.5, 0, 0.0));
    let checker = ao_under(masked_ceiling(0.5, 16, 1.0));
    assert_eq!(open, 1.0, "a fully transparent ceiling occludes nothing");
    assert!(solid < 0.5, "{solid}");
    assert!(
        solid + 0.1 < checker && checker + 0.1 < open,
        "half the ceiling: {solid} < {checker} < {open}"
    );
    // The same through a placed, refittable layer.
    let placed = Layer::placed(
        Arc::new(TriangleBvh::refittable(geometry(&masked_ceiling(
            0.0, 16, 1.0,
        )))),
        glam::Affine3A::from_translation(Vec3::Y * 0.5),
    );
    let through_layer = AoTracer::from_layers(vec![placed])
        .trace(&[Vec3::ZERO], &[Vec3::Y], &params)
        .unwrap()
        .ao[0];
    assert!(
        (through_layer - checker).abs() < 0.02,
        "{through_layer} vs {checker}"
    );
}

#[test]
fn the_default_trellis_has_holes() {
    let s = default_scene();
    let m = &s.meshes[s.instances[TRELLIS].mesh];
    assert!(m.alpha.is_some() && m.double_sided);
    let pts = generate_points(m, 64.0, 1).unwrap();
    let full = generate_points(
        &Mesh {
            alpha: None,
            ..m.clone()
        },
        64.0,
        1,
    )
    .unwrap();
    let ratio = pts.len() as f32 / full.len() as f32;
    // Bars cover 1 - (22/32)^2 = 53% of the screen.
    assert!((0.45..0.6).contains(&ratio), "{ratio}");
}
