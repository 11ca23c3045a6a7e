//! The server frame pipeline: skipping, rigid motion, end-to-end streaming.

use glam::{Affine3A, Vec3, Vec3A};
use psao_codec::{Decoder, Event, Limits, reconstruct_ao, world_to_local};
use psao_scene::*;

fn quick() -> PipelineConfig {
    PipelineConfig {
        density: 16.0,
        ao: AoParams {
            rays: 16,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    }
}

#[test]
fn a_static_scene_traces_nothing_and_sends_nothing_after_the_first_frame() {
    let mut scene = default_scene();
    scene.animations.clear();
    assert!(scene.dynamic_instances().iter().all(|d| !d));
    let mut p = Pipeline::new(scene, quick()).unwrap();
    for _ in 0..5 {
        let (frame, report) = p.step(1.0 / 60.0).unwrap();
        assert!(frame.is_none());
        assert_eq!(
            (report.traced, report.rays, report.updated, report.bytes),
            (0, 0, 0, 0)
        );
        assert!(report.points > 1000);
    }
}

#[test]
fn rigid_motion_away_from_geometry_sends_only_transforms() {
    let mut scene = Scene::default();
    // A floor far below (more than R away) and a box that moves in the air.
    scene.add(
        Mesh::quad(
            Vec3::new(-10.0, -5.0, -10.0),
            Vec3::Z * 20.0,
            Vec3::X * 20.0,
        ),
        Affine3A::IDENTITY,
    );
    let node = scene.add_node("box", None, Trs::default());
    scene.add_on_node(Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), node);
    scene.animations.push(Animation::translation(
        "fly",
        node,
        &[(0.0, Vec3::ZERO), (10.0, Vec3::new(10.0, 0.0, 0.0))],
    ));
    let mut p = Pipeline::new(scene, quick()).unwrap();
    for _ in 0..3 {
        let (frame, report) = p.step(0.1).unwrap();
        assert_eq!(report.transforms, 1);
        // Only the box's own points are re-traced (the floor is out of
        // reach), and a convex box does not occlude itself: the only
        // "updates" are retries of points dropped by full cells.
        let box_stats = p.table(1).unwrap().stats();
        assert_eq!(report.traced, (box_stats.stored + box_stats.dropped) as u64);
        assert_eq!(report.updated, box_stats.dropped as u64);
        let frame = frame.expect("a transform is news");
        assert_eq!(frame.stats.points, 0, "{:?}", frame.stats);
    }
}

#[test]
fn default_scene_streams_end_to_end() {
    let mut p = Pipeline::new(default_scene(), quick()).unwrap();
    let mut client = Decoder::new(Limits::default());
    let kf = p.keyframe().unwrap();
    assert!(matches!(
        client.receive(&kf.bytes),
        Ok(Event::Applied { keyframe: true, .. })
    ));
    let (mut traced, mut total, mut updated) = (0u64, 0u64, 0u64);
    for _ in 0..30 {
        let (frame, report) = p.step(1.0 / 60.0).unwrap();
        traced += report.traced;
        total += report.points;
        updated += report.updated;
        assert_eq!(
            report.transforms, 2,
            "the box and the walker move every frame"
        );
        assert_eq!(report.deformed, 1, "the walker's pose changes");
        let frame = frame.expect("the box moved");
        assert!(matches!(
            client.receive(&frame.bytes),
            Ok(Event::Applied { .. })
        ));
    }
    assert!(updated > 0, "the box changes AO near it");
    assert!(
        traced * 10 < total,
        "skipping: traced {traced} of {total} point-frames"
    );
    // The mirror equals the server's tables and transforms.
    for i in 0..p.instance_count() {
        let t = p.table(i).unwrap();
        let m = client.mirror().instance(i as u32).unwrap();
        assert!(
            m.words() == t.words() && m.buckets() == t.buckets(),
            "instance {i}"
        );
        let tr = m.transform().unwrap().affine();
        assert_eq!(tr, p.transform(i).unwrap());
    }
    // A stretch of floor far from everything reconstructs bright.
    let (x, nx) = world_to_local(&Affine3A::IDENTITY, Vec3::new(8.0, 0.0, 10.0), Vec3::Y).unwrap();
    let ao = reconstruct_ao(client.mirror().instance(0).unwrap(), x, nx);
    assert!(ao > 0.8, "an open stretch of floor is bright: {ao}");
    // At every point the server holds, the client's reconstruction (eq.
    // 2-4, a weighted blend of the neighbours) matches the server's value.
    for i in [0, MOVING_BOX, WALKER] {
        let (table, mirror) = (
            p.table(i).unwrap(),
            client.mirror().instance(i as u32).unwrap(),
        );
        // Where the client looks them up (bind space for the walker).
        let (pos, nrm) = p.stored_points(i).unwrap();
        let (mut sum, mut n) = (0.0f64, 0u32);
        for k in 0..pos.len() as u32 {
            let psao_codec::Placement::Stored { cell, slot } = table.placement(k) else {
                continue;
            };
            let server = psao_codec::PointWord(table.cell(cell)[slot as usize]).ao();
            let client_ao = reconstruct_ao(mirror, pos[k as usize], nrm[k as usize]);
            sum += (client_ao - server).abs() as f64;
            n += 1;
        }
        let mean = sum / n as f64;
        assert!(
            n >= 5 && mean < 0.03,
            "instance {i}: mean |client - server| {mean} over {n}"
        );
    }
}

#[test]
fn runs_are_deterministic() {
    let run = || {
        let mut p = Pipeline::new(default_scene(), quick()).unwrap();
        let mut bytes = vec![p.keyframe().unwrap().bytes.to_vec()];
        for _ in 0..5 {
            bytes.push(p.step(1.0 / 60.0).unwrap().0.unwrap().bytes.to_vec());
        }
        bytes
    };
    assert_eq!(run(), run());
}

#[test]
fn the_default_scene_moves_only_its_box_and_its_walker() {
    let scene = default_scene();
    assert!(scene.validate().is_ok());
    let dynamic = scene.dynamic_instances();
    let moving: Vec<usize> = (0..dynamic.len()).filter(|&i| dynamic[i]).collect();
    assert_eq!(moving, vec![MOVING_BOX, WALKER]);
    assert!(scene.instances[WALKER].skin.is_some());
    let at = |t: f32| scene.pose(t).instances[MOVING_BOX];
    assert_ne!(at(0.0), at(1.0));
    assert_eq!(at(0.0), at(8.0), "period 8 s");
    // The camera path lasts at least 10 s.
    assert!(scene.camera.as_ref().unwrap().duration() >= 10.0);
}

#[test]
fn skipping_changes_nothing_clients_see() {
    // A point's rays depend only on its id, so re-tracing a point that no
    // motion can reach gives the value it already has: the tables with and
    // without skipping must be identical, frame after frame.
    let run = |skip: bool| {
        let mut p = Pipeline::new(default_scene(), PipelineConfig { skip, ..quick() }).unwrap();
        let mut traced = 0;
        for _ in 0..12 {
            traced += p.step(1.0 / 20.0).unwrap().1.traced;
        }
        let words: Vec<Vec<u32>> = (0..p.instance_count())
            .map(|i| p.table(i).unwrap().words().to_vec())
            .collect();
        (words, traced)
    };
    let (with_skip, traced_skip) = run(true);
    let (without, traced_all) = run(false);
    assert!(with_skip == without, "skipping changed the streamed state");
    assert!(
        traced_skip * 10 < traced_all,
        "{traced_skip} vs {traced_all}"
    );
}

#[test]
fn points_known_open_cast_no_ray_and_send_the_same_frames() {
    // A point with nothing within reach of its rays is open without a
    // ray: the same frames, byte for byte, with a ray budget too (its
    // choices stand), with early decisions (it decides as its rays
    // would) and with settling; without early decisions exactly its rays
    // fewer are cast.
    let early = Some(EarlyDecisions::default());
    for (budget, early, settle_steps) in [
        (RayBudget::Unlimited, None, 0),
        (RayBudget::Rays(800), None, 0),
        (RayBudget::Unlimited, None, 2),
        (RayBudget::Unlimited, early, 0),
        (RayBudget::Rays(800), early, 0),
    ] {
        let config = PipelineConfig {
            budget,
            early,
            settle_steps,
            ..quick()
        };
        points_known_open_under(config);
    }
}

fn points_known_open_under(config: PipelineConfig) {
    let what = format!(
        "{:?}, early {}, settling {}",
        config.budget,
        config.early.is_some(),
        config.settle_steps
    );
    let run = |skip_open: bool| {
        let config = PipelineConfig {
            skip_open,
            ..config.clone()
        };
        let mut p = Pipeline::new(default_scene(), config).unwrap();
        let (mut frames, mut rays, mut open, mut waited) = (Vec::new(), 0, 0, 0);
        for _ in 0..12 {
            let (frame, r) = p.step(1.0 / 20.0).unwrap();
            frames.push(frame.map(|f| f.bytes));
            rays += r.rays;
            open += r.open;
            waited += r.waiting;
        }
        (frames, rays, open, waited)
    };
    let (frames, rays, open, waited) = run(true);
    let (frames_traced, rays_traced, none, _) = run(false);
    // The budget is tight enough that points wait.
    assert_eq!(
        waited > 0,
        config.budget != RayBudget::Unlimited,
        "{what}: {waited}"
    );
    assert!(
        frames == frames_traced,
        "{what}: knowing points open changed a frame"
    );
    assert_eq!(none, 0);
    assert!(open > 20, "{what}: {open} points known open");
    if config.early.is_none() {
        assert_eq!(
            rays + open * u64::from(config.ao.rays),
            rays_traced,
            "{what}"
        );
    } else {
        // Early decisions would have cast some of an open point's rays.
        assert!(rays < rays_traced, "{what}: {rays} {rays_traced}");
    }
}

/// Where point `id` of `table` is stored, decoded to instance-local space.
fn stored_position(table: &psao_codec::GridTable, id: u32) -> Option<Vec3> {
    let psao_codec::Placement::Stored { cell, slot } = table.placement(id) else {
        return None;
    };
    let key = table.buckets().iter().find(|e| e.cell == cell)?.key;
    let def = table.def();
    let cell_pos = def.cell_of_key(key)?;
    let word = psao_codec::PointWord(table.cell(cell)[slot as usize]);
    Some(def.cell_min(cell_pos) + word.frac() * def.cell_size)
}

/// RiggedSimple over a floor, streamed 20 steps to a client: the
/// pipeline, the client, the skinned instance, and the frame bytes sent.
fn stream_rigged_simple(bind_space: bool) -> (Pipeline, Decoder, usize, usize) {
    let mut scene = load_gltf(std::path::Path::new("tests/data/RiggedSimple.glb")).unwrap();
    let i = scene
        .instances
        .iter()
        .position(|x| x.skin.is_some())
        .unwrap();
    scene.add(
        Mesh::quad(Vec3::new(-3.0, -3.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0),
        Affine3A::IDENTITY,
    );
    let config = PipelineConfig {
        density: 200.0,
        bind_space,
        ..quick()
    };
    let mut p = Pipeline::new(scene, config).unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let (mut deformed, mut updated, mut bytes) = (0, 0, 0);
    for _ in 0..20 {
        let (frame, r) = p.step(1.0 / 30.0).unwrap();
        deformed += r.deformed;
        updated += r.updated;
        if let Some(f) = frame {
            bytes += f.bytes.len();
            assert!(matches!(
                client.receive(&f.bytes),
                Ok(Event::Applied { .. })
            ));
        }
    }
    assert!(deformed > 10, "the skin moves: {deformed} of 20 frames");
    assert!(updated > 0);
    let table = p.table(i).unwrap();
    let m = client.mirror().instance(i as u32).unwrap();
    assert!(m.words() == table.words() && m.buckets() == table.buckets());
    (p, client, i, bytes)
}

/// Point format 1: a skinned instance's points stay where the bind pose
/// has them, so only their AO is sent, in fewer bytes than the posed
/// stream (which moves every point with the skin), and the client's
/// mirror says the instance is in bind space.
#[test]
fn bind_space_points_never_move_and_only_their_ao_is_sent() {
    let (p, client, i, bind_bytes) = stream_rigged_simple(true);
    let (_, _, _, posed_bytes) = stream_rigged_simple(false);
    let table = p.table(i).unwrap();
    assert!(table.def().bind_space());
    assert!(
        client
            .mirror()
            .instance(i as u32)
            .unwrap()
            .def()
            .bind_space()
    );
    let floor = p.instance_count() - 1;
    assert!(
        !p.table(floor).unwrap().def().bind_space(),
        "a rigid floor stays format 0"
    );
    let bind = &p.points(i).unwrap().positions;
    let quantum = table.def().cell_size / psao_codec::POSITION_QUANTA as f32;
    let mut checked = 0;
    for (k, &pos) in bind.iter().enumerate() {
        let Some(stored) = stored_position(table, k as u32) else {
            continue;
        };
        checked += 1;
        let off = (stored - pos) / quantum;
        assert!(
            off.abs().max_element() <= 0.5 + 1e-3,
            "point {k}: {off} quanta off"
        );
    }
    assert!(
        checked * 10 >= bind.len() * 9,
        "{checked} of {}",
        bind.len()
    );
    assert!(
        bind_bytes * 2 < posed_bytes,
        "bind space sent {bind_bytes} bytes, posed {posed_bytes}"
    );
}

#[test]
fn skinned_points_follow_the_skin_to_the_client() {
    // The posed baseline (point format 0): points move with the skin.
    let (p, _, i, _) = stream_rigged_simple(false);
    let table = p.table(i).unwrap();
    // Every stored point sits where the skin has it now, within the
    // position threshold (3 quanta) plus rounding.
    let (now, _) = p.current_points(i).unwrap();
    let bind = &p.points(i).unwrap().positions;
    let quantum = table.def().cell_size / psao_codec::POSITION_QUANTA as f32;
    let (mut checked, mut moved) = (0, 0);
    for (k, &pos) in now.iter().enumerate() {
        let Some(stored) = stored_position(table, k as u32) else {
            continue;
        };
        checked += 1;
        let off = (stored - pos) / quantum;
        assert!(off.length() <= 3.0 + 1.0, "point {k}: {off} quanta off");
        if pos.distance(bind[k]) > 10.0 * quantum.max_element() {
            moved += 1;
        }
    }
    assert!(checked > 100, "{checked}");
    assert!(moved > 10, "the pose bends the mesh: {moved} points moved");
}

#[test]
fn split_and_whole_bvhs_trace_the_same_scene() {
    let run = |split_bvh: bool| {
        let mut p = Pipeline::new(
            default_scene(),
            PipelineConfig {
                split_bvh,
                ..quick()
            },
        )
        .unwrap();
        for _ in 0..6 {
            p.step(1.0 / 20.0).unwrap();
        }
        (0..p.instance_count())
            .flat_map(|i| p.table(i).unwrap().words().to_vec())
            .collect::<Vec<u32>>()
    };
    let (a, b) = (run(true), run(false));
    assert_eq!(a.len(), b.len());
    // Rays in a moving instance's local space round differently from
    // world-space rays: a grazing ray may flip, nothing more.
    let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    assert!(
        differ * 200 < a.len(),
        "{differ} of {} words differ",
        a.len()
    );
}

#[test]
fn culling_waits_for_points_to_come_into_view() {
    // A floor and a box sliding over it at x = 0; the camera first looks
    // away (towards -x, from x = 20), then turns to the box.
    let mut scene = Scene::default();
    scene.add(
        Mesh::quad(Vec3::new(-4.0, 0.0, -4.0), Vec3::Z * 8.0, Vec3::X * 8.0),
        Affine3A::IDENTITY,
    );
    let node = scene.add_node("box", None, Trs::default());
    scene.add_on_node(Mesh::cuboid(Vec3::splat(-0.25), Vec3::splat(0.25)), node);
    scene.animations.push(Animation::translation(
        "slide",
        node,
        &[
            (0.0, Vec3::new(-1.0, 0.25, 0.0)),
            (10.0, Vec3::new(1.0, 0.25, 0.0)),
        ],
    ));
    let eye = Vec3::new(20.0, 1.0, 0.0);
    let key = |time: f32, target: Vec3| CameraKey { time, eye, target };
    scene.camera = Some(CameraPath {
        keys: vec![
            key(0.0, Vec3::new(20.0, 1.0, 10.0)),
            key(1.0, Vec3::new(20.0, 1.0, 10.0)),
            key(1.5, Vec3::ZERO),
        ],
        fov_y: 0.5,
    });
    let cull = ViewerCull {
        aspect: 1.0,
        far: 100.0,
        margin: 0.0,
    };
    // Without a camera path nothing is culled until views are given.
    let mut viewers = Pipeline::new(
        Scene {
            camera: None,
            ..scene.clone()
        },
        PipelineConfig {
            cull: Some(cull),
            ..quick()
        },
    )
    .unwrap();
    let (_, r) = viewers.step(0.1).unwrap();
    assert!(r.traced > 0 && r.culled == 0, "{r:?}");
    // No one looking: everything waits.
    viewers.set_views(Views::Frusta(Vec::new()));
    let (_, r) = viewers.step(0.1).unwrap();
    assert!(r.traced == 0 && r.culled > 0, "{r:?}");
    // The union of two views, one of them on the box: it is traced.
    let frustum = |target: Vec3| {
        Camera {
            eye,
            target,
            fov_y: 0.5,
        }
        .frustum(1.0, cull.near(), cull.far)
    };
    viewers.set_views(Views::Frusta(vec![
        frustum(Vec3::new(20.0, 1.0, 10.0)),
        frustum(Vec3::ZERO),
    ]));
    let (_, r) = viewers.step(0.1).unwrap();
    assert!(r.traced > 0 && r.culled == 0, "{r:?}");
    // Views::All culls nothing either.
    viewers.set_views(Views::All);
    let (_, r) = viewers.step(0.1).unwrap();
    assert!(r.traced > 0 && r.culled == 0, "{r:?}");
    let mut p = Pipeline::new(
        scene,
        PipelineConfig {
            cull: Some(cull),
            ..quick()
        },
    )
    .unwrap();
    // Looking away: nothing traced, the box's surroundings wait.
    let mut waiting = 0;
    for _ in 0..8 {
        let (_, r) = p.step(0.1).unwrap();
        assert_eq!(r.traced, 0, "{r:?}");
        waiting = r.culled;
    }
    assert!(waiting > 10, "{waiting}");
    // Turned to the box: the waiting points are traced, none wait.
    let mut traced = 0;
    for _ in 0..10 {
        let (_, r) = p.step(0.1).unwrap();
        traced += r.traced;
        waiting = r.culled;
    }
    assert_eq!(waiting, 0);
    assert!(traced > 10, "{traced}");
}

#[test]
fn a_skinned_instance_without_animation_keeps_its_points_in_its_grid() {
    // The mesh hangs from a node 5 m along x, its skin from a joint at the
    // origin: the joint matrix moves the vertices 5 m back in the
    // instance's space, away from the bind-pose bounds.
    let mut s = Scene::default();
    let holder = s.add_node("holder", None, Trs::from_translation(Vec3::X * 5.0));
    let joint = s.add_node("joint", None, Trs::default());
    s.skins.push(Skin {
        name: "s".into(),
        joints: vec![joint],
        inverse_bind: vec![Affine3A::IDENTITY],
    });
    let mut quad = Mesh::quad(Vec3::ZERO, Vec3::X, Vec3::Z);
    quad.skin = Some(SkinWeights {
        joints: vec![[0; 4]; 4],
        weights: vec![[1.0, 0.0, 0.0, 0.0]; 4],
    });
    let i = s.add_on_node(quad, holder);
    s.instances[i].skin = Some(0);
    let p = Pipeline::new(s, quick()).unwrap();
    let stats = p.table(i).unwrap().stats();
    assert!(stats.stored > 0);
    assert_eq!(stats.out_of_grid, 0, "{stats:?}");
}

#[test]
fn a_degenerate_pose_holds_the_instance_and_others_carry_on() {
    let mut scene = Scene::default();
    let a = scene.add_node("a", None, Trs::default());
    let b = scene.add_node("b", None, Trs::default());
    scene.add_on_node(Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), a);
    scene.add_on_node(Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)), b);
    scene.animations.push(Animation::translation(
        "slide",
        a,
        &[(0.0, Vec3::ZERO), (10.0, Vec3::X * 10.0)],
    ));
    // b shrinks to nothing between 1 s and 2 s, then comes back.
    scene.animations.push(Animation {
        name: "vanish".into(),
        channels: vec![Channel {
            node: b,
            times: vec![0.0, 1.0, 2.0, 10.0],
            keys: Keys::Scale(vec![Vec3::ONE, Vec3::ZERO, Vec3::ZERO, Vec3::ONE]),
            interpolation: Interpolation::Step,
        }],
    });
    let mut p = Pipeline::new(scene, quick()).unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let mut held = 0;
    for _ in 0..30 {
        let (frame, r) = p.step(0.1).unwrap();
        held += r.held;
        if let Some(f) = frame {
            client.receive(&f.bytes).unwrap();
        }
    }
    assert!(held >= 9, "b is held while its scale is zero: {held}");
    let m = client
        .mirror()
        .instance(0)
        .unwrap()
        .transform()
        .unwrap()
        .affine();
    assert_eq!(
        m,
        p.transform(0).unwrap(),
        "a kept moving and its client followed"
    );
    assert!((p.transform(0).unwrap().translation.x - 3.0).abs() < 1e-4);
}

/// The sequence of the transform `client` holds for instance `i`.
fn transform_sequence(client: &Decoder, i: usize) -> u32 {
    client
        .mirror()
        .instance(i as u32)
        .and_then(|m| m.transform())
        .expect("the instance and its transform")
        .sequence
}

#[test]
fn instances_can_be_placed_by_scene_events() {
    let mut p = Pipeline::new(default_scene(), quick()).unwrap();
    let to = Affine3A::from_translation(Vec3::new(9.0, 0.25, 10.0));
    let e = p.place_instance(0, to).unwrap_err();
    assert!(e.to_string().contains("static"), "{e}");
    assert!(p.place_instance(99, to).is_err());
    assert!(
        p.place_instance(MOVING_BOX, Affine3A::from_scale(Vec3::ZERO))
            .is_err()
    );
    p.place_instance(MOVING_BOX, to).unwrap();
    for _ in 0..3 {
        p.step(1.0 / 60.0).unwrap();
        assert_eq!(p.transform(MOVING_BOX).unwrap(), to);
    }
    // Placed again where it is: the placement is still sent, with a newer
    // transform sequence, so a client can tell it was accepted.
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let seq = |c: &Decoder| transform_sequence(c, MOVING_BOX);
    let before = seq(&client);
    // Not placed: held where it is, nothing new sent for it.
    if let (Some(f), _) = p.step(1.0 / 60.0).unwrap() {
        client.receive(&f.bytes).unwrap();
    }
    assert_eq!(seq(&client), before);
    p.place_instance(MOVING_BOX, to).unwrap();
    let (frame, _) = p.step(1.0 / 60.0).unwrap();
    client
        .receive(&frame.expect("the transform is sent").bytes)
        .unwrap();
    assert_eq!(seq(&client), before.wrapping_add(1));
    assert_eq!(p.transform(MOVING_BOX).unwrap(), to);
}

/// A deforming instance placed where it already is, while its skin moves,
/// still sends its placement (a newer transform sequence).
#[test]
fn a_skinned_instance_placed_where_it_is_sends_its_placement() {
    let scene = cesium_man_scene();
    let i = (0..scene.instances.len())
        .find(|&i| scene.instances[i].skin.is_some())
        .unwrap();
    let mut p = Pipeline::new(scene, quick()).unwrap();
    let mut client = Decoder::new(Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let seq = |c: &Decoder| transform_sequence(c, i);
    let before = seq(&client);
    let (frame, r) = p.step(0.25).unwrap();
    assert_eq!(r.deformed, 1, "{r:?}");
    if let Some(f) = frame {
        client.receive(&f.bytes).unwrap();
    }
    assert_eq!(seq(&client), before, "walking in place: no new transform");
    let at = p.transform(i).unwrap();
    p.place_instance(i, at).unwrap();
    let (frame, r) = p.step(0.25).unwrap();
    assert_eq!(r.deformed, 1, "{r:?}");
    client.receive(&frame.unwrap().bytes).unwrap();
    assert_eq!(seq(&client), before.wrapping_add(1));
}

/// CesiumMan's staged scene with the character's mesh cut into two
/// primitives on the same node and skin (as a glTF mesh of several
/// primitives imports), the vertices shared.
fn cesium_man_in_two_primitives() -> Scene {
    let mut s = cesium_man_scene();
    let i = (0..s.instances.len())
        .find(|&i| s.instances[i].skin.is_some())
        .expect("a skinned instance");
    let mesh = s.meshes[s.instances[i].mesh].clone();
    let half = mesh.triangle_count() / 2 * 3;
    let mut first = mesh.clone();
    first.indices.truncate(half);
    let mut second = mesh;
    second.indices.drain(..half);
    let m = s.instances[i].mesh;
    s.meshes[m] = first;
    s.meshes.push(second);
    let mut twin = s.instances[i].clone();
    twin.mesh = s.meshes.len() - 1;
    s.instances.push(twin);
    s
}

#[test]
fn the_primitives_of_one_skinned_mesh_deform_as_one_layer_with_the_same_ao() {
    let config = quick();
    let mut whole = Pipeline::new(cesium_man_scene(), config.clone()).unwrap();
    let mut split = Pipeline::new(cesium_man_in_two_primitives(), config.clone()).unwrap();
    assert_eq!(split.instance_count(), whole.instance_count() + 1);
    for _ in 0..8 {
        whole.step(1.0 / 30.0).unwrap();
        split.step(1.0 / 30.0).unwrap();
    }
    // One layer for the two primitives: the floor and the figure, as for
    // the mesh in one piece.
    let (a, b) = (whole.current_tracer(), split.current_tracer());
    assert_eq!(a.layer_counts(), b.layer_counts());
    assert_eq!(a.triangles(), b.triangles());
    // Probes around the walking figure see the same occluders, bit for bit.
    let probes: Vec<Vec3> = (0..400)
        .map(|k| {
            let u = |j| uniform(3, k, j);
            Vec3::new(u(0) - 0.5, u(1) * 1.8, u(2) - 0.5)
        })
        .collect();
    let normals: Vec<Vec3> = (0..400)
        .map(|k| Vec3::new(uniform(4, k, 0) - 0.5, 0.5, uniform(4, k, 1) - 0.5).normalize())
        .collect();
    let ra = a.trace(&probes, &normals, &config.ao).unwrap();
    let rb = b.trace(&probes, &normals, &config.ao).unwrap();
    assert_eq!(ra, rb);
    assert!(ra.ao.iter().any(|&x| x < 0.9), "the probes see the figure");
}

#[test]
fn the_hall_has_many_moving_parts_inside_its_walls_and_streams() {
    let scene = hall(HallParams {
        props: 40,
        figures: 2,
    });
    scene.validate().unwrap();
    let dynamic = scene.dynamic_instances();
    let moving = dynamic.iter().filter(|&&d| d).count();
    assert!(moving >= 42, "{moving} moving instances");
    // Props and figures stay inside the 36 x 18 x 6 m hall at every
    // second of their animations, and so does the camera.
    let inside =
        |p: Vec3| p.cmpge(Vec3::splat(-0.01)).all() && p.cmple(Vec3::new(36.01, 6.01, 18.01)).all();
    for t in 0..60 {
        let pose = scene.pose(t as f32);
        for (i, m) in pose.instances.iter().enumerate() {
            if dynamic[i] {
                assert!(inside(m.translation.into()), "instance {i} at {t} s: {m:?}");
            }
        }
        let cam = scene.camera.as_ref().unwrap().at(t as f32 * 0.5);
        assert!(inside(cam.eye), "camera at {t} s: {:?}", cam.eye);
    }
    // The default hall holds the props and figures its parameters say.
    assert_eq!(
        hall_scene()
            .dynamic_instances()
            .iter()
            .filter(|&&d| d)
            .count(),
        moving + 120 + 2
    );
    let mut p = Pipeline::new(
        scene,
        PipelineConfig {
            density: 2.0,
            ao: AoParams {
                rays: 8,
                ..AoParams::default()
            },
            ..PipelineConfig::default()
        },
    )
    .unwrap();
    let (_, report) = p.step(0.25).unwrap();
    assert!(report.traced > 0 && report.transforms > 0, "{report:?}");
    let (direct, boxed) = p.current_tracer().layer_counts();
    assert!(boxed >= 42 && direct == 0, "({direct}, {boxed})");
}

#[test]
fn transforms_are_judged_relative_to_their_own_scale() {
    // A 7 cm model placed by a node that scales by 1e-4 (ToyCar's case:
    // determinant 1e-12) loads and streams; so does a mirrored one.
    let tiny = Affine3A::from_scale_rotation_translation(
        Vec3::splat(1e-4),
        glam::Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        Vec3::new(0.0, 0.01, 0.0),
    );
    assert!(invertible(&tiny));
    assert!(invertible(
        &(tiny * Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0)))
    ));
    let mut scene = Scene::default();
    scene.add(
        Mesh::quad(Vec3::new(-0.1, 0.0, -0.1), Vec3::Z * 0.2, Vec3::X * 0.2),
        Affine3A::IDENTITY,
    );
    scene.add(Mesh::cuboid(Vec3::splat(-300.0), Vec3::splat(300.0)), tiny);
    // Density counts per world square metre: 2e5 over the 6 cm box's
    // 216 cm^2 (2.16e6 in its own units) spawns about 4,300.
    let config = PipelineConfig {
        density: 2e5,
        ao: AoParams {
            radius: 0.02,
            rays: 8,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let p = Pipeline::new(scene.clone(), config.clone()).unwrap();
    let kept = p.points(1).unwrap().len();
    assert!((1_900..2_400).contains(&kept), "{kept} points on the box");
    // The same box modelled in metres, unscaled: as many points.
    let mut metres = scene.clone();
    metres.meshes[1] = Mesh::cuboid(Vec3::splat(-0.03), Vec3::splat(0.03));
    metres.instances[1].transform = Affine3A::from_translation(Vec3::new(0.0, 0.01, 0.0));
    let q = Pipeline::new(metres, config.clone()).unwrap();
    let same = q.points(1).unwrap().len() as f64;
    assert!((kept as f64 / same - 1.0).abs() < 0.05, "{kept} and {same}");
    // Singular (an axis scaled to zero) or sheared almost flat: refused,
    // whatever the scale.
    for bad in [
        Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0)),
        Affine3A::from_cols(Vec3A::X, Vec3A::X + Vec3A::Y * 1e-7, Vec3A::Z, Vec3A::ZERO),
        Affine3A::from_scale(Vec3::splat(f32::INFINITY)),
    ] {
        assert!(!invertible(&bad), "{bad:?}");
        let mut s = scene.clone();
        s.instances[1].transform = bad;
        let e = Pipeline::new(s, config.clone()).unwrap_err();
        assert!(matches!(e, SceneError::BadTransform { instance: 1 }), "{e}");
    }
}

/// The scene-wide point budget is checked before any point is made, from
/// an estimate that tracks the points a scene really keeps.
#[test]
fn the_point_budget_refuses_a_scene_before_making_its_points() {
    let config = quick();
    let p = Pipeline::new(default_scene(), config.clone()).unwrap();
    let kept: usize = (0..p.instance_count())
        .map(|i| p.points(i).map_or(0, |s| s.len()))
        .sum();
    // Just under what the scene keeps: refused, naming both numbers.
    let budget = (kept as u64) * 9 / 10;
    let Err(SceneError::TooManyPoints { estimated, max }) = Pipeline::new(
        default_scene(),
        PipelineConfig {
            max_points: budget,
            ..config.clone()
        },
    ) else {
        panic!("a scene over its budget was accepted");
    };
    assert_eq!(max, budget);
    let ratio = estimated as f64 / kept as f64;
    assert!(
        (0.9..1.1).contains(&ratio),
        "estimated {estimated}, kept {kept}"
    );
    // A node scale of 1e4 (a model in decimicrons...) at the default budget
    // is refused at once, not after allocating 10^8 times the points.
    let mut huge = default_scene();
    for inst in &mut huge.instances {
        inst.transform = glam::Affine3A::from_scale(glam::Vec3::splat(1e4)) * inst.transform;
    }
    let Err(e) = Pipeline::new(huge, config) else {
        panic!("a scene 10^8 times larger was accepted");
    };
    assert!(
        matches!(
            e,
            SceneError::TooManyPoints {
                max: DEFAULT_MAX_POINTS,
                ..
            }
        ),
        "{e}"
    );
}
