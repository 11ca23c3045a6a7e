//! Per-pixel passes: the G-buffer from primary rays, the ray-traced
//! reference, and the PSAO client image from a mirror.

use glam::{Affine3A, Vec3};
use psao_codec::{Decoder, Limits, Mirror};
use psao_eval::*;
use psao_scene::*;

/// An 8 m x 8 m floor at y = 0 (facing +Y) with a 1 m box on it.
fn floor_and_box() -> Scene {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-4.0, 0.0, -4.0), Vec3::Z * 8.0, Vec3::X * 8.0).subdivided(3),
        Affine3A::IDENTITY,
    );
    s.add(
        Mesh::cuboid(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5)),
        Affine3A::IDENTITY,
    );
    s
}

fn looking_down(w: u32, h: u32) -> View {
    View::new(
        Camera {
            eye: Vec3::new(0.0, 5.0, 0.01),
            target: Vec3::ZERO,
            fov_y: 60f32.to_radians(),
        },
        w,
        h,
    )
    .unwrap()
}

#[test]
fn the_gbuffer_sees_what_the_camera_sees() {
    let scene = floor_and_box();
    let posed = PosedScene::new(&scene, 0.0).unwrap();
    let view = looking_down(33, 33);
    let g = posed.gbuffer(&view);
    assert_eq!(g.pixels(), 33 * 33);
    // The centre pixel looks straight down at the box's top at y = 1.
    let c = 16 * 33 + 16;
    assert_eq!(g.instance[c], 1, "the box");
    assert!((g.position[c].y - 1.0).abs() < 1e-4, "{:?}", g.position[c]);
    assert!(
        (g.depth[c] - 4.0).abs() < 1e-2,
        "depth along the view axis: {}",
        g.depth[c]
    );
    assert!(g.normal[c].dot(Vec3::Y) > 0.999, "{:?}", g.normal[c]);
    // A corner pixel sees the floor (60 degrees from 5 m covers ~5.8 m).
    assert_eq!(g.instance[0], 0, "the floor");
    assert!(g.position[0].y.abs() < 1e-4);
    // The view point of a pixel at its depth is the world point.
    let to_view = view.world_to_view();
    for k in [0, c, 33 * 33 - 1] {
        let (px, py) = ((k % 33) as u32, (k / 33) as u32);
        let p = view.view_point(px, py, g.depth[k]);
        let q = to_view.transform_point3(g.position[k]);
        assert!((p - q).length() < 1e-3, "pixel {k}: {p:?} against {q:?}");
    }
}

#[test]
fn pixels_that_see_nothing_are_open_and_marked() {
    let scene = floor_and_box();
    let posed = PosedScene::new(&scene, 0.0).unwrap();
    // Looking up at the sky.
    let view = View::new(
        Camera {
            eye: Vec3::new(0.0, 2.0, 0.0),
            target: Vec3::new(0.0, 10.0, 0.5),
            fov_y: 0.5,
        },
        8,
        8,
    )
    .unwrap();
    let g = posed.gbuffer(&view);
    assert_eq!(g.covered(), 0);
    assert!(g.instance.iter().all(|&i| i == NO_INSTANCE));
    assert!(g.depth.iter().all(|d| d.is_infinite()));
    let ao = ray_traced_ao(&posed.tracer(), &g, &AoParams::default()).unwrap();
    assert!(ao.iter().all(|&a| a == 1.0));
    let img = psao_image(&Mirror::new(), &g).unwrap();
    assert!(img.ao.iter().all(|&a| a == 1.0));
    assert_eq!(img.unknown, 0);
}

#[test]
fn views_are_checked() {
    let cam = Camera {
        eye: Vec3::ZERO,
        target: Vec3::X,
        fov_y: 1.0,
    };
    assert!(View::new(cam, 0, 10).is_err());
    assert!(View::new(cam, 10, MAX_IMAGE_SIDE + 1).is_err());
    assert!(
        View::new(
            Camera {
                target: cam.eye,
                ..cam
            },
            4,
            4
        )
        .is_err()
    );
    assert!(View::new(Camera { fov_y: 3.2, ..cam }, 4, 4).is_err());
    assert!(
        View::new(
            Camera {
                eye: Vec3::NAN,
                ..cam
            },
            4,
            4
        )
        .is_err()
    );
    assert!(PosedScene::new(&floor_and_box(), f32::NAN).is_err());
    // Looking straight down keeps a sensible up vector (no NaN).
    let down = View::new(
        Camera {
            eye: Vec3::new(0.0, 5.0, 0.0),
            target: Vec3::ZERO,
            fov_y: 1.0,
        },
        4,
        4,
    )
    .unwrap();
    assert!(down.world_to_view().is_finite());
    // A G-buffer whose attributes disagree with its size is an error.
    let scene = floor_and_box();
    let posed = PosedScene::new(&scene, 0.0).unwrap();
    let mut g = posed.gbuffer(&down);
    g.depth.pop();
    assert!(g.check().is_err());
    assert!(ray_traced_ao(&posed.tracer(), &g, &AoParams::default()).is_err());
    assert!(psao_image(&Mirror::new(), &g).is_err());
}

#[test]
fn the_reference_darkens_the_crease_and_opens_the_floor() {
    let scene = floor_and_box();
    let posed = PosedScene::new(&scene, 0.0).unwrap();
    let view = looking_down(41, 41);
    let g = posed.gbuffer(&view);
    let p = AoParams {
        rays: 128,
        ..AoParams::default()
    };
    let ao = ray_traced_ao(&posed.tracer(), &g, &p).unwrap();
    // The box top is open; floor pixels beside the box are darker than
    // floor pixels far from it.
    let c = 20 * 41 + 20;
    assert!(ao[c] > 0.99, "box top {}", ao[c]);
    let floor: Vec<(f32, f32)> = (0..g.pixels())
        .filter(|&k| g.instance[k] == 0)
        .map(|k| {
            let d = g.position[k];
            let gap = (d.x.abs() - 0.5).max(d.z.abs() - 0.5);
            (gap, ao[k])
        })
        .collect();
    let mean = |lo: f32, hi: f32| {
        let v: Vec<f32> = floor
            .iter()
            .filter(|(gap, _)| *gap >= lo && *gap < hi)
            .map(|x| x.1)
            .collect();
        assert!(!v.is_empty(), "no floor pixels {lo}..{hi} from the box");
        v.iter().sum::<f32>() / v.len() as f32
    };
    let (near, far) = (mean(0.0, 0.35), mean(0.8, 10.0));
    assert!(near < far - 0.03, "near the box {near}, far {far}");
    assert!(far > 0.97, "open floor {far}");
    // Same inputs, same image.
    assert_eq!(ao, ray_traced_ao(&posed.tracer(), &g, &p).unwrap());
}

/// RMSE of the PSAO client image against a per-pixel reference of the
/// default scene at time 0, for a density.
fn psao_rmse(density: f32) -> f64 {
    let scene = default_scene();
    let config = PipelineConfig {
        density,
        ao: AoParams {
            rays: 32,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let mut p = Pipeline::new(scene.clone(), config).unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let camera = scene.camera.as_ref().unwrap().at(0.0);
    let view = View::new(camera, 64, 36).unwrap();
    let posed = PosedScene::new(&scene, 0.0).unwrap();
    let g = posed.gbuffer(&view);
    let reference = ray_traced_ao(
        &posed.tracer(),
        &g,
        &AoParams {
            rays: 256,
            ..AoParams::default()
        },
    )
    .unwrap();
    let img = psao_image(client.mirror(), &g).unwrap();
    assert_eq!(img.unknown, 0, "every instance has its transform");
    rmse(&reference, &img.ao).unwrap()
}

#[test]
fn psao_error_falls_as_points_get_denser() {
    let (sparse, dense) = (psao_rmse(16.0), psao_rmse(128.0));
    assert!(
        dense < sparse * 0.9,
        "RMSE at 16 points/m^2 {sparse}, at 128 {dense}"
    );
    assert!(dense < 0.05, "RMSE at 128 points/m^2: {dense}");
}

/// Each covered pixel of `img` is eq. 2-4 at its position taken into
/// its instance's space with the transform the mirror holds.
fn assert_reconstructed(mirror: &Mirror, g: &GBuffer, img: &ClientImage) {
    for k in 0..g.pixels() {
        let id = g.instance[k];
        if id == NO_INSTANCE {
            continue;
        }
        let inst = mirror.instance(id).unwrap();
        let (x, n) = psao_codec::world_to_local(
            &inst.transform().unwrap().affine(),
            g.position[k],
            g.normal[k],
        )
        .unwrap();
        assert_eq!(
            img.ao[k],
            psao_codec::reconstruct_ao(inst, x, n),
            "pixel {k}"
        );
    }
}

#[test]
fn the_client_image_uses_the_last_received_transform() {
    // The box slides 1 m along x in the first second.
    let mut scene = Scene::default();
    scene.add(
        Mesh::quad(Vec3::new(-4.0, 0.0, -4.0), Vec3::Z * 8.0, Vec3::X * 8.0).subdivided(3),
        Affine3A::IDENTITY,
    );
    let node = scene.add_node("box", None, Trs::default());
    scene.add_on_node(
        Mesh::cuboid(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5)),
        node,
    );
    scene.animations.push(Animation::translation(
        "slide",
        node,
        &[(0.0, Vec3::ZERO), (1.0, Vec3::X), (2.0, Vec3::ZERO)],
    ));
    let mut p = Pipeline::new(
        scene.clone(),
        PipelineConfig {
            density: 64.0,
            ao: AoParams {
                rays: 16,
                ..AoParams::default()
            },
            ..PipelineConfig::default()
        },
    )
    .unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let view = looking_down(24, 24);
    let g0 = PosedScene::new(&scene, 0.0).unwrap().gbuffer(&view);
    let before = psao_image(client.mirror(), &g0).unwrap();
    assert_eq!(before.unknown, 0);
    assert_reconstructed(client.mirror(), &g0, &before);
    // An instance the mirror does not hold counts as unknown.
    let mut strange = g0.clone();
    strange.instance[0] = 7;
    assert_eq!(psao_image(client.mirror(), &strange).unwrap().unknown, 1);

    let (frame, _) = p.step(1.0).unwrap();
    let g1 = PosedScene::new(&scene, 1.0).unwrap().gbuffer(&view);
    // Not yet received: the client still holds the old transform.
    let stale = psao_image(client.mirror(), &g1).unwrap();
    assert_reconstructed(client.mirror(), &g1, &stale);
    client.receive(&frame.unwrap().bytes).unwrap();
    let moved = client
        .mirror()
        .instance(1)
        .unwrap()
        .transform()
        .unwrap()
        .affine();
    assert!((moved.translation - glam::Vec3A::X).length() < 1e-5);
    let after = psao_image(client.mirror(), &g1).unwrap();
    assert_reconstructed(client.mirror(), &g1, &after);
    // The box top is open wherever the box is, once the client knows.
    let top = |g: &GBuffer, img: &ClientImage| {
        (0..g.pixels())
            .filter(|&k| g.instance[k] == 1 && g.normal[k].y > 0.99)
            .map(|k| img.ao[k])
            .fold(f32::INFINITY, f32::min)
    };
    assert!(top(&g0, &before) > 0.95 && top(&g1, &after) > 0.95);
}

#[test]
fn single_sided_faces_seen_from_behind_are_culled_as_gltf_says() {
    let view_from = |y: f32| {
        View::new(
            Camera {
                eye: Vec3::new(0.01, y, 0.02),
                target: Vec3::new(0.0, 0.0, 0.0),
                fov_y: 0.5,
            },
            16,
            16,
        )
        .unwrap()
    };
    let seen = |scene: &Scene, y: f32| {
        let g = PosedScene::new(scene, 0.0).unwrap().gbuffer(&view_from(y));
        g.covered()
    };
    // A 4 m square facing up (+y), and far below it a second square
    // facing up, seen through the first from below.
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::Z * 4.0, Vec3::X * 4.0),
        Affine3A::IDENTITY,
    );
    let all = 16 * 16;
    assert_eq!(seen(&s, 3.0), all, "its front, from above");
    assert_eq!(seen(&s, -3.0), 0, "its back, from below: culled");
    let mut both = s.clone();
    both.meshes[0].double_sided = true;
    assert_eq!(seen(&both, -3.0), all, "double-sided: seen from both sides");
    // Mirrored by a negative scale, its front faces down (-y): the camera
    // below sees it, the camera above does not.
    let mut mirrored = s.clone();
    mirrored.instances[0].transform = Affine3A::from_scale(Vec3::new(1.0, -1.0, 1.0));
    assert_eq!(seen(&mirrored, -3.0), all, "a mirrored front, from below");
    assert_eq!(seen(&mirrored, 3.0), 0, "a mirrored back, from above");
    // What lies behind a culled face is what the camera sees.
    s.add(
        Mesh::quad(Vec3::new(-20.0, 5.0, -20.0), Vec3::X * 40.0, Vec3::Z * 40.0),
        Affine3A::IDENTITY,
    );
    let g = PosedScene::new(&s, 0.0)
        .unwrap()
        .gbuffer(&view_from(3.0 - 6.0));
    assert!(g.instance.iter().all(|&i| i == 1), "{:?}", g.instance);
}

/// A 4 m square facing up (+y) at y = 0 whose vertex normals are all `n`.
fn square_with_normals(n: Vec3) -> Mesh {
    let mut quad = Mesh::quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::Z * 4.0, Vec3::X * 4.0);
    for v in &mut quad.normals {
        *v = n;
    }
    quad
}

/// Every covered pixel of `g` (all 64 of them) has shading normal `world`
/// and bind-space normal `bind`.
fn assert_normals(g: &GBuffer, world: Vec3, bind: Vec3) {
    assert_eq!(g.covered(), 64);
    for k in 0..g.pixels() {
        assert!((g.normal[k] - world).length() < 1e-5, "{:?}", g.normal[k]);
        assert!(
            (g.bind_normal[k] - bind).length() < 1e-5,
            "{:?}",
            g.bind_normal[k]
        );
    }
}

/// The side a pixel shades is told by its triangle's face, as a
/// rasterizer's front-facing test: a front face whose vertex normals lean
/// so far that the interpolated normal points away from the camera (a
/// grazing silhouette of a smooth mesh) keeps that normal, not its inverse
/// pointing into the surface; a double-sided face seen from behind still
/// flips, position normal and bind normal alike.
#[test]
fn the_shaded_side_follows_the_face_not_a_leaning_vertex_normal() {
    // Seen from above at 45 degrees, from +x.
    let camera = Camera {
        eye: Vec3::new(3.0, 3.0, 0.01),
        target: Vec3::ZERO,
        fov_y: 0.3,
    };
    let view = View::new(camera, 8, 8).unwrap();
    // A square facing up (+y) whose normals all lean 79 degrees towards
    // -x: still on the face's side, but pointing away from the camera.
    let lean = Vec3::new(-1.0, 0.2, 0.0).normalize();
    let mut s = Scene::default();
    s.add(square_with_normals(lean), Affine3A::IDENTITY);
    let g = PosedScene::new(&s, 0.0).unwrap().gbuffer(&view);
    assert_normals(&g, lean, lean);
    // Mirrored (its front faces down) and seen from below: a front face,
    // its leaning normals kept as the mirror places them.
    let mut mirrored = Scene::default();
    mirrored.add(
        square_with_normals(lean),
        Affine3A::from_scale(Vec3::new(1.0, -1.0, 1.0)),
    );
    let from_below = View::new(
        Camera {
            eye: Vec3::new(3.0, -3.0, 0.01),
            ..camera
        },
        8,
        8,
    )
    .unwrap();
    let g = PosedScene::new(&mirrored, 0.0)
        .unwrap()
        .gbuffer(&from_below);
    assert_normals(&g, Vec3::new(lean.x, -lean.y, lean.z), lean);
    // Double-sided and seen from below: the normals flip to face the
    // camera's side of the face.
    let mut both = Scene::default();
    let mut quad = Mesh::quad(Vec3::new(-2.0, 0.0, -2.0), Vec3::Z * 4.0, Vec3::X * 4.0);
    quad.double_sided = true;
    both.add(quad, Affine3A::IDENTITY);
    let below = View::new(
        Camera {
            eye: Vec3::new(0.0, -3.0, 0.01),
            fov_y: 0.5,
            ..camera
        },
        8,
        8,
    )
    .unwrap();
    let g = PosedScene::new(&both, 0.0).unwrap().gbuffer(&below);
    assert_eq!(g.covered(), 64);
    assert!(g.normal.iter().all(|n| (*n + Vec3::Y).length() < 1e-5));
    assert!(g.bind_normal.iter().all(|n| (*n + Vec3::Y).length() < 1e-5));
}

#[test]
fn the_world_to_clip_matrix_puts_each_pixels_surface_at_its_centre() {
    // A slanted view of the floor and the box, wider than high.
    let view = View::new(
        Camera {
            eye: Vec3::new(-3.0, 2.5, 4.0),
            target: Vec3::new(0.2, 0.3, -0.1),
            fov_y: 0.9,
        },
        40,
        24,
    )
    .unwrap();
    let posed = PosedScene::new(&floor_and_box(), 0.0).unwrap();
    let g = posed.gbuffer(&view);
    let to_clip = view.world_to_clip();
    let mut checked = 0;
    for py in 0..view.height {
        for px in 0..view.width {
            let k = (py * view.width + px) as usize;
            if g.instance[k] == NO_INSTANCE {
                continue;
            }
            let c = to_clip * g.position[k].extend(1.0);
            let u = (c.x / c.w + 1.0) / 2.0 * view.width as f32;
            let v = (1.0 - c.y / c.w) / 2.0 * view.height as f32;
            assert!(
                (u - (px as f32 + 0.5)).abs() < 1e-3,
                "pixel ({px}, {py}): u {u}"
            );
            assert!(
                (v - (py as f32 + 0.5)).abs() < 1e-3,
                "pixel ({px}, {py}): v {v}"
            );
            assert!(
                (c.w - g.depth[k]).abs() < 1e-4 * g.depth[k],
                "pixel ({px}, {py}): w {}",
                c.w
            );
            checked += 1;
        }
    }
    assert!(checked > 200, "{checked} pixels see something");
}

#[test]
fn the_hidden_test_changes_nothing_where_nothing_stands_between() {
    // The floor and the box from above: no surface covers another's points
    // and faces a pixel, so every pixel is eq. 2-4's, bit for bit.
    let scene = floor_and_box();
    let mut pipeline = Pipeline::new(
        scene.clone(),
        PipelineConfig::with_density_and_rays(64.0, 16),
    )
    .unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&pipeline.keyframe().unwrap().bytes).unwrap();
    let view = looking_down(48, 32);
    let g = PosedScene::new(&scene, 0.0).unwrap().gbuffer(&view);
    let plain = psao_image(client.mirror(), &g).unwrap();
    let seen = psao_image_seen(client.mirror(), &g, &view).unwrap();
    assert_eq!(plain, seen);
    // A view of another size than the G-buffer's is an error.
    assert!(psao_image_seen(client.mirror(), &g, &looking_down(48, 31)).is_err());
}
