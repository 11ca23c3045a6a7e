//! The ray budget and ray reuse (issue 20): rays motion cannot reach are
//! not cast again, frames stay byte-identical, and under a budget no point
//! waits longer than `max_wait` steps. Settling and the lead (issue 15):
//! where motion has passed, clients hold what a full trace gives, to the
//! quantization; a lead poses the scene ahead of the clock.

use std::time::Duration;

use glam::{Affine3A, Vec3};
use psao_codec::PointWord;
use psao_codec::wire::point::quantize_ao;
use psao_scene::*;

fn config(estimator: Estimator) -> PipelineConfig {
    PipelineConfig {
        density: 32.0,
        ao: AoParams {
            rays: 24,
            estimator,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    }
}

/// Every frame's bytes and report over `ticks` steps of 1/30 s.
fn run(scene: &Scene, c: PipelineConfig, ticks: u32) -> (Vec<Vec<u8>>, Vec<FrameReport>) {
    let mut p = Pipeline::new(scene.clone(), c).unwrap();
    let (mut frames, mut reports) = (Vec::new(), Vec::new());
    frames.push(p.keyframe().unwrap().bytes.to_vec());
    for _ in 0..ticks {
        let (f, r) = p.step(1.0 / 30.0).unwrap();
        frames.push(f.map(|f| f.bytes.to_vec()).unwrap_or_default());
        reports.push(r);
    }
    (frames, reports)
}

fn total(r: &[FrameReport], f: impl Fn(&FrameReport) -> u64) -> u64 {
    r.iter().map(f).sum()
}

#[test]
fn reused_rays_give_the_same_frames_byte_for_byte() {
    for (scene, name) in [
        (default_scene(), "default"),
        (cesium_man_scene(), "cesium man"),
    ] {
        // (Laine-Karras with settling at 64 rays: at 24 its AO moves in
        // steps of 1/24, above the send threshold's 8/255, so every change
        // is sent and nothing is left to settle.)
        for (est, settle, rays) in [
            (Estimator::ClosestHit, 0, 24),
            (Estimator::ClosestHit, 1, 24),
            (Estimator::LaineKarras, 0, 24),
            (Estimator::LaineKarras, 1, 64),
        ] {
            let mut c = PipelineConfig {
                settle_steps: settle,
                ..config(est)
            };
            c.ao.rays = rays;
            let (a, ra) = run(&scene, c.clone(), 24);
            let (b, rb) = run(
                &scene,
                PipelineConfig {
                    ray_reuse: false,
                    ..c
                },
                24,
            );
            assert!(
                a == b,
                "{name} {est:?} settle {settle}: ray reuse changed a frame"
            );
            let (rays_a, rays_b) = (total(&ra, |r| r.rays), total(&rb, |r| r.rays));
            assert!(
                rays_a * 10 < rays_b * 9,
                "{name} {est:?}: {rays_a} rays against {rays_b}"
            );
            assert!(total(&ra, |r| r.unreached) > 0, "{name} {est:?}");
            assert_eq!(total(&rb, |r| r.unreached + r.rays_kept), 0);
            if est == Estimator::ClosestHit {
                assert!(total(&ra, |r| r.rays_kept) > 0, "{name}: scores kept");
            }
            // Settled points are in these frames, when asked for.
            assert_eq!(total(&ra, |r| r.settled) > 0, settle > 0, "{name} {est:?}");
            assert!(ra.iter().all(|r| r.waiting == 0 && r.budget.is_none()));
        }
    }
}

/// A floor, a static block, and beside it a cross of two bars turning in
/// place on an animated node: what moves stays inside one envelope, and
/// many floor and block rays hit the block before they could reach it.
fn turning_cross() -> Scene {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-3.0, 0.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0).subdivided(3),
        Affine3A::IDENTITY,
    );
    // (Clear of the floor, and the bars of each other: no point lies
    // inside another surface, where it would be buried.)
    s.add(
        Mesh::cuboid(Vec3::new(0.45, 0.02, -0.5), Vec3::new(0.6, 0.3, 0.5)),
        Affine3A::IDENTITY,
    );
    let node = s.add_node("cross", None, Trs::default());
    s.add_on_node(
        Mesh::cuboid(Vec3::new(-0.4, 0.05, -0.05), Vec3::new(0.4, 0.12, 0.05)),
        node,
    );
    s.add_on_node(
        Mesh::cuboid(Vec3::new(-0.05, 0.15, -0.4), Vec3::new(0.05, 0.22, 0.4)),
        node,
    );
    // 90 degrees a second (3 a step at 30 Hz) for 2 s, then still until
    // the loop starts again at 10 s.
    let turn = |deg: f32| glam::Quat::from_rotation_y(deg.to_radians());
    s.animations.push(Animation {
        name: "turn".into(),
        channels: vec![Channel {
            node,
            times: vec![0.0, 1.0, 2.0, 10.0],
            keys: Keys::Rotation(vec![turn(0.0), turn(90.0), turn(180.0), turn(180.0)]),
            interpolation: Interpolation::Linear,
        }],
    });
    s
}

#[test]
fn a_part_turning_in_place_keeps_its_envelope_and_reused_rays_stay_exact() {
    // Planning learns, point by point, which rays reach the envelope of
    // what turns (and which hit the static block first); from then on it
    // tests only those. Frames must not change; under a budget of rays per
    // step (points wait, some are traced in full), what clients hold of
    // the static instances must catch up with a full trace.
    let scene = turning_cross();
    let c = config(Estimator::ClosestHit);
    let (a, ra) = run(&scene, c.clone(), 45);
    let (b, _) = run(
        &scene,
        PipelineConfig {
            ray_reuse: false,
            ..c.clone()
        },
        45,
    );
    assert!(a == b, "ray reuse changed a frame");
    assert!(total(&ra, |r| r.unreached) > 0 && total(&ra, |r| r.rays_kept) > 0);
    // Under a budget: nothing held drifts from a full trace by more than
    // the send threshold and the wait, and a rested scene catches up.
    let budget = total(&ra, |r| r.rays) / 45 / 4;
    for ray_reuse in [true, false] {
        let mut p = Pipeline::new(
            scene.clone(),
            PipelineConfig {
                budget: RayBudget::Rays(budget),
                ray_reuse,
                ..c.clone()
            },
        )
        .unwrap();
        p.keyframe().unwrap();
        let mut waited = 0;
        for _ in 0..45 {
            let (_, r) = p.step(1.0 / 30.0).unwrap();
            assert!(r.rays <= budget + r.overdue * c.ao.rays as u64, "{r:?}");
            assert!(r.oldest_wait <= r.wait_bound, "{r:?}");
            waited = waited.max(r.waiting);
        }
        assert!(waited > 0, "the budget made points wait");
        // The cross turns until 2 s (60 steps), then rests: everything
        // catches up within the longest wait. The floor and the block
        // hold a full trace, to the send threshold (8 steps of 1/255).
        for _ in 0..(15 + 2 * c.max_wait_limit) {
            p.step(1.0 / 30.0).unwrap();
        }
        let floor = p.current_points(0).unwrap().0.len() as u32;
        for (i, base) in [(0, 0), (1, floor)] {
            let err = worst_held_error(&mut p, i, base, &c.ao);
            assert!(
                err <= 8.5 / 255.0,
                "ray reuse {ray_reuse}: instance {i} off by {} steps",
                err * 255.0
            );
        }
    }
}

/// A floor, and a box on an animated node (so it can be placed); the
/// test places it.
fn sliding_box() -> (Scene, usize) {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-3.0, 0.0, -3.0), Vec3::Z * 6.0, Vec3::X * 6.0).subdivided(3),
        Affine3A::IDENTITY,
    );
    let node = s.add_node("box", None, Trs::default());
    let b = s.add_on_node(
        Mesh::cuboid(Vec3::new(-0.3, 0.0, -0.3), Vec3::new(0.3, 0.6, 0.3)),
        node,
    );
    let (from, to) = (Vec3::new(-1.5, 0.0, 0.0), Vec3::new(1.5, 0.0, 0.0));
    s.animations.push(Animation::translation(
        "slide",
        node,
        &[(0.0, from), (2.0 / 3.0, to)],
    ));
    (s, b)
}

/// [`sliding_box`] with a wall beside the box's path (x = 0.6).
fn box_by_a_wall() -> (Scene, usize) {
    let (mut scene, b) = sliding_box();
    scene.add(
        Mesh::quad(Vec3::new(0.6, 0.0, -1.5), Vec3::Y * 1.5, Vec3::Z * 3.0).subdivided(2),
        Affine3A::IDENTITY,
    );
    (scene, b)
}

/// Places [`sliding_box`]'s box `b` for step `t`: 3 m in 20 steps of
/// 0.15 m from x = -1.5, then it rests where it was put.
fn slide(p: &mut Pipeline, b: usize, t: u32) {
    if t < 20 {
        let x = -1.5 + 0.15 * t as f32;
        p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
            .unwrap();
    }
}

/// What clients hold of every stored point of instance `i`, beside a full
/// trace of the scene now: (point, held AO, traced AO). (The points'
/// normals are taken as stored: for an instance that turns, they are not
/// the world's.)
fn held_and_fresh(p: &mut Pipeline, i: usize, base: u32, ao: &AoParams) -> Vec<(usize, f32, f32)> {
    let tracer = p.current_tracer();
    let (pos, nrm) = p.current_points(i).unwrap();
    let m = p.transform(i).unwrap();
    let world: Vec<Vec3> = pos.iter().map(|&q| m.transform_point3(q)).collect();
    let ids: Vec<u32> = (0..pos.len() as u32).map(|k| base + k).collect();
    let fresh = tracer.trace_ids(&ids, &world, nrm, ao).unwrap();
    let table = p.table(i).unwrap();
    (0..pos.len())
        .filter_map(|k| match table.placement(k as u32) {
            psao_codec::Placement::Stored { cell, slot } => Some((
                k,
                PointWord(table.cell(cell)[slot as usize]).ao(),
                fresh.ao[k],
            )),
            _ => None,
        })
        .collect()
}

/// Per point of every instance (numbered on through the instances),
/// whether what clients hold lies more than the send threshold from a
/// full trace now ([`held_and_fresh`]).
fn held_off(p: &mut Pipeline, ao: &AoParams) -> Vec<bool> {
    let counts: Vec<u32> = (0..p.instance_count())
        .map(|i| p.points(i).unwrap().len() as u32)
        .collect();
    let mut off = vec![false; counts.iter().sum::<u32>() as usize];
    let mut base = 0;
    for (i, &count) in counts.iter().enumerate() {
        for (k, held, fresh) in held_and_fresh(p, i, base, ao) {
            off[base as usize + k] = (held - fresh).abs() > 8.5 / 255.0;
        }
        base += count;
    }
    off
}

/// The largest difference between what clients hold of instance `i`'s
/// points and a full trace now ([`held_and_fresh`]).
fn worst_held_error(p: &mut Pipeline, i: usize, base: u32, ao: &AoParams) -> f32 {
    held_and_fresh(p, i, base, ao)
        .into_iter()
        .map(|(_, held, fresh)| (held - fresh).abs())
        .fold(0.0, f32::max)
}

#[test]
fn where_motion_has_left_a_point_open_clients_hold_it_open() {
    // The default: no settling. The box slides across the floor and
    // rests; the floor it left behind is open again. A change into open
    // is sent whatever the threshold, so no point there keeps a darkness
    // below the threshold (before, the floor the box passed kept up to
    // `ao_steps` of it for good).
    let (scene, b) = sliding_box();
    let c = config(Estimator::ClosestHit);
    assert_eq!(c.settle_steps, 0);
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    let mut was_dark = vec![false; p.points(0).unwrap().len()];
    for t in 0..24 {
        slide(&mut p, b, t);
        p.step(1.0 / 30.0).unwrap();
        for (k, held, _) in held_and_fresh(&mut p, 0, 0, &ao) {
            was_dark[k] |= quantize_ao(held) < 255;
        }
    }
    let open: Vec<_> = held_and_fresh(&mut p, 0, 0, &ao)
        .into_iter()
        .filter(|&(_, _, fresh)| quantize_ao(fresh) == 255)
        .collect();
    let passed = open.iter().filter(|&&(k, _, _)| was_dark[k]).count();
    assert!(passed > 50, "only {passed} open points were ever held dark");
    let dark: Vec<_> = open
        .iter()
        .filter(|&&(_, held, _)| quantize_ao(held) != 255)
        .collect();
    assert!(
        dark.is_empty(),
        "{} open points held dark: {dark:?}",
        dark.len()
    );
}

#[test]
fn under_a_budget_no_point_waits_past_max_wait_and_all_catch_up() {
    let (scene, b) = sliding_box();
    let c = PipelineConfig {
        budget: RayBudget::Rays(240),
        max_wait: 3,
        max_wait_limit: 3,
        ..config(Estimator::ClosestHit)
    };
    let ao = c.ao;
    let mut p = Pipeline::new(scene.clone(), c).unwrap();
    let mut waited = false;
    for t in 0..40 {
        slide(&mut p, b, t);
        let (_, r) = p.step(1.0 / 30.0).unwrap();
        // Reported on every step that traces.
        assert!(r.rays == 0 || r.budget == Some(240), "{:?}", r.budget);
        assert!(r.oldest_wait <= 3, "step {t}: waited {}", r.oldest_wait);
        waited |= r.waiting > 0;
        if r.overdue == 0 {
            // Only points forced by their wait go past the budget.
            assert!(r.rays <= 240, "step {t}: {} rays", r.rays);
        }
    }
    assert!(waited, "the budget made points wait");
    let (_, r) = p.step(1.0 / 30.0).unwrap();
    assert_eq!(r.waiting, 0, "every point caught up once the box rests");
    // What clients hold of the floor is what a full trace gives, within
    // the send threshold (8 steps of 1/255).
    let err = worst_held_error(&mut p, 0, 0, &ao);
    assert!(err <= 8.5 / 255.0, "floor AO off by {err}");
}

/// The sliding box across the floor for 60 steps under a budget of 48
/// rays a step (far below what the points it reaches need), with the
/// bound on waiting from 2 up to `limit`: the steps that cast more rays
/// than the budget, and the highest bound in force. Every step, no point
/// waited longer than the bound in force.
fn demand_beyond_the_budget(limit: u32) -> (usize, u32) {
    let (scene, b) = sliding_box();
    let c = PipelineConfig {
        budget: RayBudget::Rays(48),
        max_wait: 2,
        max_wait_limit: limit,
        ..config(Estimator::ClosestHit)
    };
    let mut p = Pipeline::new(scene, c).unwrap();
    let (mut over, mut highest) = (0, 0);
    for t in 0..60 {
        let x = -1.5 + 0.05 * t as f32;
        p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
            .unwrap();
        let (_, r) = p.step(1.0 / 30.0).unwrap();
        assert!(
            r.oldest_wait <= r.wait_bound && (2..=limit).contains(&r.wait_bound),
            "step {t}: waited {} under a bound of {}",
            r.oldest_wait,
            r.wait_bound
        );
        over += usize::from(r.rays > 48);
        highest = highest.max(r.wait_bound);
    }
    (over, highest)
}

/// The turning cross ([`turning_cross`]) turned 135 degrees (where it
/// rests, nothing is as it was) under a budget far below demand, the
/// bound on waiting free to rise past `max_wait` (so points that wait long
/// are planned late: once, when the budget takes them, against the boxes
/// of every step they waited), then at rest until nothing waits, settling
/// on: the largest difference between what clients hold of the floor and
/// the block and a full trace of the scene now, and the highest bound.
fn held_error_after_demand_beyond_the_budget() -> (f32, u32) {
    let c = PipelineConfig {
        budget: RayBudget::Rays(64),
        max_wait: 2,
        max_wait_limit: 40,
        settle_steps: 1,
        plan_late: true,
        ..config(Estimator::ClosestHit)
    };
    let ao = c.ao;
    let mut p = Pipeline::new(turning_cross(), c).unwrap();
    let mut highest = 0;
    for _ in 0..45 {
        highest = highest.max(p.step(1.0 / 30.0).unwrap().1.wait_bound);
    }
    let mut rest = 0;
    loop {
        // Steps of no time: the cross stays where it is.
        let (_, r) = p.step(0.0).unwrap();
        rest += 1;
        if r.waiting == 0 && r.traced == 0 {
            break;
        }
        assert!(
            rest < 5000,
            "points still wait 5000 steps after the cross rests"
        );
    }
    let floor = p.current_points(0).unwrap().0.len() as u32;
    let error = worst_held_error(&mut p, 0, 0, &ao).max(worst_held_error(&mut p, 1, floor, &ao));
    (error, highest)
}

#[test]
fn points_planned_late_trace_every_ray_motion_reached_while_they_waited() {
    let (error, highest) = held_error_after_demand_beyond_the_budget();
    assert!(
        highest > 2,
        "the bound never rose: no point was planned late"
    );
    // A ray reached while a point waited and not traced again would leave
    // its old score in the point's AO.
    assert!(error <= 0.51 / 255.0, "held AO off by {}", error * 255.0);
}

#[test]
fn under_demand_beyond_the_budget_the_bound_on_waiting_rises_and_steps_keep_the_budget() {
    // A fixed bound: points that reach it are traced past the budget.
    let (over_fixed, fixed) = demand_beyond_the_budget(2);
    assert_eq!(fixed, 2);
    // A bound that follows demand rises, and fewer steps go past the
    // budget.
    let (over, highest) = demand_beyond_the_budget(40);
    assert!(highest > 2, "the bound never rose");
    assert!(
        over < over_fixed,
        "{over} steps past the budget with the bound following demand, {over_fixed} with it fixed"
    );
}

/// The worst AO error clients hold on the sliding box's own points over
/// the steps it slides up to a wall (its AO changes as it nears it),
/// under a budget far below what its points need.
fn box_error_while_it_moves(movers_every_step: bool) -> f32 {
    let (scene, b) = box_by_a_wall();
    let c = PipelineConfig {
        budget: RayBudget::Rays(48),
        max_wait: 6,
        movers_every_step,
        ..config(Estimator::ClosestHit)
    };
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    let floor = p.points(0).unwrap().len() as u32;
    let mut worst = 0.0f32;
    // From x = -1.2 to 0.24: its face ends 0.06 m from the wall.
    for t in 0..13 {
        let x = -1.2 + 0.12 * t as f32;
        p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
            .unwrap();
        let (_, r) = p.step(1.0 / 30.0).unwrap();
        if movers_every_step {
            // The box's points go past the budget, as overdue ones.
            assert!(r.overdue >= p.points(b).unwrap().len() as u64, "{r:?}");
        }
        worst = worst.max(worst_held_error(&mut p, b, floor, &ao));
    }
    worst
}

#[test]
fn movers_traced_every_step_hold_their_ao_under_any_budget() {
    // Traced every step it moves: what clients hold of the box is a full
    // trace of its pose, to the send threshold (8 steps of 1/255).
    let every = box_error_while_it_moves(true);
    assert!(
        every <= 8.5 / 255.0,
        "box AO off by {} steps",
        every * 255.0
    );
    // Waiting their turn, its points hold AO of older poses (this is what
    // the option removes).
    let waiting = box_error_while_it_moves(false);
    assert!(
        waiting > every && waiting > 8.5 / 255.0,
        "waiting points held AO within {} steps",
        waiting * 255.0
    );
}

/// What clients hold of box `b`'s points (ids after `base`) against a
/// full trace of `scene` with the box placed at `held`, the transform
/// clients hold: the largest AO difference.
fn held_error_at(
    p: &Pipeline,
    (scene, c): (&Scene, &PipelineConfig),
    b: usize,
    base: u32,
    held: Affine3A,
) -> f32 {
    let mut there = Pipeline::new(scene.clone(), c.clone()).unwrap();
    there.place_instance(b, held).unwrap();
    there.step(0.0).unwrap();
    assert_eq!(there.transform(b), Some(held));
    let tracer = there.current_tracer();
    let (pos, nrm) = p.current_points(b).unwrap();
    let world: Vec<Vec3> = pos.iter().map(|&q| held.transform_point3(q)).collect();
    let ids: Vec<u32> = (0..pos.len() as u32).map(|k| base + k).collect();
    let fresh = tracer.trace_ids(&ids, &world, nrm, &c.ao).unwrap();
    let table = p.table(b).unwrap();
    (0..pos.len())
        .filter_map(|k| match table.placement(k as u32) {
            psao_codec::Placement::Stored { cell, slot } => {
                Some((PointWord(table.cell(cell)[slot as usize]).ao() - fresh.ao[k]).abs())
            }
            _ => None,
        })
        .fold(0.0, f32::max)
}

/// One step of [`whole_box_run`].
struct WholeBoxStep {
    /// Whether the transform clients hold moved.
    moved: bool,
    /// What clients hold of the box against a full trace with the box
    /// where they hold it (the largest AO difference).
    error: f32,
    /// Steps from where clients hold the box to where it is: positive
    /// where they hold a pose it had, negative where one it is to have.
    lag: i32,
    /// Points traced, rays cast, and the budget.
    traced: u64,
    rays: u64,
    budget: u64,
    /// The longest any point has waited, and the bound in force.
    oldest_wait: u32,
    wait_bound: u32,
}

/// The box of `scene` (a [`sliding_box`], maybe by a wall) under a budget
/// its points exceed by half, held whole as `movers_whole` says
/// ([`PipelineConfig::movers_whole`]): each step, with the box's points.
fn whole_box_run(scene: (Scene, usize), movers_whole: MoversWhole) -> (Vec<WholeBoxStep>, usize) {
    let (scene, b) = scene;
    let mut c = PipelineConfig {
        max_wait: 6,
        movers_whole,
        ..config(Estimator::ClosestHit)
    };
    // A budget the box's points cost 1.5 times: never traced whole by the
    // budget alone (but within the twice it may cost to be held whole).
    let n = Pipeline::new(scene.clone(), c.clone())
        .unwrap()
        .points(b)
        .unwrap()
        .len() as u64;
    c.budget = RayBudget::Rays(n * u64::from(c.ao.rays) * 2 / 3);
    let mut p = Pipeline::new(scene.clone(), c.clone()).unwrap();
    let floor = p.points(0).unwrap().len() as u32;
    let id = p.table(b).unwrap().id();
    let mut client = psao_codec::Decoder::new(psao_codec::Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let held = |c: &psao_codec::Decoder| c.mirror().instance(id).unwrap().transform().cloned();
    let mut steps = Vec::new();
    // The slide takes 20 steps (and the animation starts over); 10 more
    // (more than the bound of 6 a part is held for).
    for _ in 0..30 {
        let before = held(&client);
        let (f, r) = p.step(1.0 / 30.0).unwrap();
        if let Some(f) = f {
            client.receive(&f.bytes).unwrap();
        }
        let now = Affine3A::from_cols_array(&held(&client).expect("a transform").matrix);
        // The box's pose j steps from this one, as the scene poses it.
        let at = |j: i32| scene.pose_at(p.posed_at() + j as f64 / 30.0).instances[b];
        let lag = (-8..=8)
            .filter(|&j| at(-j).abs_diff_eq(now, 1e-4))
            .min_by_key(|j: &i32| j.abs())
            .expect("a pose of the box within 8 steps");
        steps.push(WholeBoxStep {
            moved: held(&client) != before,
            error: held_error_at(&p, (&scene, &c), b, floor, now),
            lag,
            traced: r.traced,
            rays: r.rays,
            budget: r.budget.unwrap(),
            oldest_wait: r.oldest_wait,
            wait_bound: r.wait_bound,
        });
    }
    (steps, p.points(b).unwrap().len())
}

#[test]
fn a_rigid_mover_held_whole_keeps_its_transform_with_its_points() {
    let (whole, n) = whole_box_run(box_by_a_wall(), MoversWhole::On);
    let sent: Vec<usize> = (0..whole.len()).filter(|&t| whole[t].moved).collect();
    // The budget cannot trace the box every step: it is held in some, and
    // traced whole (its transform sent) in others.
    assert!(
        sent.len() >= 2 && sent.len() < 20,
        "transform sent in steps {sent:?}"
    );
    for &t in &sent {
        // Sent only with every point of the box traced at one pose.
        assert!(
            whole[t].traced >= n as u64,
            "step {t}: {} traced of {n}",
            whole[t].traced
        );
    }
    for (t, w) in whole.iter().enumerate() {
        // What clients hold of the box is a full trace where they hold
        // it, to the send threshold (8 steps of 1/255): the pose a stage
        // traced it in.
        assert!(
            w.error <= 8.5 / 255.0,
            "step {t}: box AO off by {} steps",
            w.error * 255.0
        );
        assert!(
            w.lag.abs() <= 6,
            "step {t}: clients hold the box {} steps off",
            w.lag
        );
        // Traced over several steps, the box costs no step more than its
        // budget.
        assert!(
            w.rays <= w.budget,
            "step {t}: {} rays of {}",
            w.rays,
            w.budget
        );
    }
    // A stage traces the box over several steps at the pose it will have
    // when the stage ends: clients get its points with the pose the box
    // is in then (the animation is known ahead), not an older one.
    for &t in &sent {
        assert_eq!(whole[t].lag, 0, "step {t}");
    }
    // Between sends they hold it a few steps behind.
    assert!(
        whole.iter().any(|w| w.lag >= 2),
        "the box was traced every step"
    );
    // Without it the transform goes out every step of the slide, while
    // the box's points wait their turn.
    let (apart, _) = whole_box_run(box_by_a_wall(), MoversWhole::Off);
    assert!(
        apart[..20].iter().all(|s| s.moved),
        "{:?}",
        apart.iter().map(|s| s.moved).collect::<Vec<_>>()
    );
}

/// Steps of the slide (the first 20) in which the box moved but clients
/// kept the transform they held: it was held whole.
fn held_in_the_slide(steps: &[WholeBoxStep]) -> usize {
    steps[..20].iter().filter(|s| !s.moved).count()
}

#[test]
fn auto_holds_a_part_whose_ao_changes_as_it_moves_and_not_one_sliding_on_a_floor() {
    // By the wall the box's own AO changes as it slides: once enough of
    // its points were traced (64), `Auto` holds it whole as `On` does.
    let (by_wall, _) = whole_box_run(box_by_a_wall(), MoversWhole::Auto);
    let moved: Vec<bool> = by_wall.iter().map(|s| s.moved).collect();
    assert!(held_in_the_slide(&by_wall) >= 3, "{moved:?}");
    // Until then its AO slides with it, far from a full trace where
    // clients place it; from the first send after it was first held on,
    // clients hold a full trace where they place it, to the send
    // threshold (8 steps of 1/255).
    let first_held = moved.iter().position(|&m| !m).unwrap();
    let whole_from = first_held + moved[first_held..].iter().position(|&m| m).unwrap();
    assert!(
        by_wall[..first_held].iter().any(|w| w.error > 16.0 / 255.0),
        "the box's AO never slid off"
    );
    for (t, w) in by_wall.iter().enumerate() {
        if t >= whole_from {
            assert!(
                w.error <= 8.5 / 255.0,
                "step {t}: box AO off by {}",
                w.error * 255.0
            );
        }
        assert!(w.lag.abs() <= 6, "step {t}: {} steps off", w.lag);
        // Its points waited in turns before it was held: a few steps after
        // may trace points come due past the budget, as the bound says.
        assert!(w.oldest_wait <= w.wait_bound, "step {t}");
    }
    let rays: u64 = by_wall.iter().map(|w| w.rays).sum();
    let budget: u64 = by_wall.iter().map(|w| w.budget).sum();
    assert!(rays <= budget, "{rays} rays against {budget}");
    // On an even floor it keeps its AO as it goes: `Auto` sends its
    // transform every step of the slide, as `Off` does, where `On` holds
    // it.
    let (floor, _) = whole_box_run(sliding_box(), MoversWhole::Auto);
    assert_eq!(held_in_the_slide(&floor), 0);
    let (on, _) = whole_box_run(sliding_box(), MoversWhole::On);
    assert!(held_in_the_slide(&on) > 0);
}

/// `k` boxes sliding in x, 4 m apart in z, each by a
/// wall of its own as [`box_by_a_wall`]'s: the boxes' instances.
fn boxes_by_walls(k: usize) -> (Scene, Vec<usize>) {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(
            Vec3::new(-3.0, 0.0, -3.0),
            Vec3::Z * 4.0 * k as f32,
            Vec3::X * 6.0,
        )
        .subdivided(3),
        Affine3A::IDENTITY,
    );
    let mut boxes = Vec::new();
    for j in 0..k {
        let z = 4.0 * j as f32;
        let node = s.add_node(&format!("box {j}"), None, Trs::default());
        boxes.push(s.add_on_node(
            Mesh::cuboid(Vec3::new(-0.3, 0.0, z - 0.3), Vec3::new(0.3, 0.6, z + 0.3)),
            node,
        ));
        s.animations.push(Animation::translation(
            &format!("slide {j}"),
            node,
            &[
                (0.0, Vec3::new(-1.5, 0.0, 0.0)),
                (2.0 / 3.0, Vec3::new(1.5, 0.0, 0.0)),
            ],
        ));
        s.add(
            Mesh::quad(Vec3::new(0.6, 0.0, z - 1.5), Vec3::Y * 1.5, Vec3::Z * 3.0).subdivided(2),
            Affine3A::IDENTITY,
        );
    }
    (s, boxes)
}

/// Per step, how many of `boxes` clients hold away from where the scene
/// has them (held whole), over `steps` steps of 1/30 s under `c`.
fn boxes_held(scene: &Scene, boxes: &[usize], c: &PipelineConfig, steps: u32) -> Vec<usize> {
    let mut p = Pipeline::new(scene.clone(), c.clone()).unwrap();
    let mut client = psao_codec::Decoder::new(psao_codec::Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let ids: Vec<u32> = boxes.iter().map(|&b| p.table(b).unwrap().id()).collect();
    (0..steps)
        .map(|_| {
            let (f, _) = p.step(1.0 / 30.0).unwrap();
            if let Some(f) = f {
                client.receive(&f.bytes).unwrap();
            }
            let pose = scene.pose_at(p.posed_at());
            (boxes.iter().zip(&ids))
                .filter(|&(&b, &id)| {
                    let held = client.mirror().instance(id).unwrap().transform().unwrap();
                    !Affine3A::from_cols_array(&held.matrix).abs_diff_eq(pose.instances[b], 1e-4)
                })
                .count()
        })
        .collect()
}

#[test]
fn auto_holds_only_the_parts_half_the_budget_affords() {
    let (scene, boxes) = boxes_by_walls(4);
    let c = PipelineConfig {
        max_wait: 6,
        ..config(Estimator::ClosestHit)
    };
    // A box's rays spread over `max_wait` steps; a budget of 5 of those:
    // half of it affords two boxes held at once, not three.
    let n = Pipeline::new(scene.clone(), c.clone())
        .unwrap()
        .points(boxes[0])
        .unwrap()
        .len() as u64;
    let per_step = (n * u64::from(c.ao.rays)).div_ceil(6);
    let c = PipelineConfig {
        budget: RayBudget::Rays(5 * per_step),
        ..c
    };
    let auto = boxes_held(&scene, &boxes, &c, 60);
    assert!(auto.iter().any(|&h| h > 0), "none held: {auto:?}");
    assert!(auto.iter().all(|&h| h <= 2), "{auto:?}");
    // `On` holds every one, whatever they cost together.
    let on = boxes_held(
        &scene,
        &boxes,
        &PipelineConfig {
            movers_whole: MoversWhole::On,
            ..c
        },
        60,
    );
    assert!(on.iter().any(|&h| h > 2), "{on:?}");
}

#[test]
fn an_automatic_budget_is_measured_and_reported() {
    let c = PipelineConfig {
        budget: RayBudget::Auto { share: 0.5 },
        ..config(Estimator::ClosestHit)
    };
    let (least, limit) = (c.max_wait, c.max_wait_limit);
    let mut p = Pipeline::new(default_scene(), c).unwrap();
    for _ in 0..12 {
        // How many rays it allows depends on this machine's speed (and
        // may be none on a loaded one): it is reported, and it never
        // holds a point back past the bound in force, itself within
        // max_wait and max_wait_limit.
        let (_, r) = p.step(1.0 / 60.0).unwrap();
        assert!(r.budget.is_some(), "{r:?}");
        assert!(r.oldest_wait <= r.wait_bound, "{r:?}");
        assert!((least..=limit).contains(&r.wait_bound), "{r:?}");
    }
}

#[test]
fn the_trace_phases_are_reported_and_lie_within_the_trace() {
    let c = PipelineConfig {
        budget: RayBudget::Rays(20_000),
        ..config(Estimator::ClosestHit)
    };
    let mut p = Pipeline::new(default_scene(), c).unwrap();
    let mut traced = 0;
    for _ in 0..6 {
        let (_, r) = p.step(1.0 / 60.0).unwrap();
        let ph = r.trace_phases;
        // Each part is timed inside the trace phase, one after the other.
        assert!(
            ph.plan + ph.choose + ph.cast + ph.apply <= r.t_trace,
            "{r:?}"
        );
        if r.traced > 0 {
            traced += 1;
            assert!(
                ph.plan > Duration::ZERO && ph.cast > Duration::ZERO,
                "{r:?}"
            );
        }
    }
    assert!(traced > 0, "the box and the walker move: points are traced");
}

/// The box slides across the floor and comes to rest; one step later,
/// what clients hold of every point of both (floor and box) against a
/// full trace of the scene as it is now: the largest AO difference.
fn held_error_after_the_box_rests(c: PipelineConfig) -> f32 {
    let (scene, b) = sliding_box();
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    for t in 0..24 {
        slide(&mut p, b, t);
        p.step(1.0 / 30.0).unwrap();
    }
    let floor = p.points(0).unwrap().len() as u32;
    worst_held_error(&mut p, 0, 0, &ao).max(worst_held_error(&mut p, b, floor, &ao))
}

#[test]
fn where_motion_has_passed_clients_hold_a_full_trace_to_the_quantization() {
    let c = PipelineConfig {
        settle_steps: 1,
        ..config(Estimator::ClosestHit)
    };
    let settled = held_error_after_the_box_rests(c.clone());
    // Half a step of 1/255 (the quantization), and float rounding.
    assert!(
        settled <= 0.51 / 255.0,
        "held AO off by {}",
        settled * 255.0
    );
    // Without settling the send threshold's worth stays behind where AO is
    // short of open (this test fails on the code before it).
    let unsettled = held_error_after_the_box_rests(PipelineConfig {
        settle_steps: 0,
        ..c
    });
    assert!(
        unsettled > 1.5 / 255.0,
        "the baseline holds AO within {} steps",
        unsettled * 255.0
    );
}

#[test]
fn settling_sends_each_point_once_and_casts_no_ray_for_it() {
    let (scene, b) = sliding_box();
    let c = PipelineConfig {
        settle_steps: 1,
        ..config(Estimator::ClosestHit)
    };
    let mut p = Pipeline::new(scene, c).unwrap();
    let mut reports = Vec::new();
    for t in 0..30 {
        if t < 10 {
            let x = -1.5 + 0.3 * t as f32;
            p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
                .unwrap();
        }
        reports.push(p.step(1.0 / 30.0).unwrap().1);
    }
    assert!(total(&reports, |r| r.settled) > 0, "points settled");
    // The step after the box rests traces nothing: what it sends is
    // settled from the last trace, with no ray cast.
    let rest = &reports[10];
    assert_eq!((rest.traced, rest.rays), (0, 0), "{rest:?}");
    assert!(rest.settled > 0 && rest.updated >= rest.settled, "{rest:?}");
    // After that, a still scene sends nothing.
    for r in &reports[11..] {
        assert_eq!((r.traced, r.updated, r.settled), (0, 0, 0), "{r:?}");
    }
}

#[test]
fn a_server_running_for_days_poses_its_scene_as_in_its_first_minute() {
    // A day and 0.2 s in: an f32 time there moves in steps of 7.8 ms,
    // which would put the box (4.5 m/s) up to 1.8 cm off (here 3.1 ms,
    // 1.4 cm). The pipeline takes each animation's time within its loop
    // from its f64 clock.
    let (scene, b) = sliding_box();
    let d = scene.animations[0].duration() as f64;
    let mut p = Pipeline::new(scene.clone(), config(Estimator::ClosestHit)).unwrap();
    p.step(86_400.0).unwrap();
    p.step(0.2).unwrap();
    assert_eq!(p.posed_at(), 86_400.0 + 0.2f32 as f64);
    let within = (p.posed_at().rem_euclid(d)) as f32;
    let x = p.transform(b).unwrap().translation.x;
    let want = scene.pose(within).instances[b].translation.x;
    assert!(
        (x - want).abs() < 1e-4,
        "at {x}, the loop's time gives {want}"
    );
    // Posed at the f32 time, it would be far off.
    let coarse = scene.pose(p.posed_time()).instances[b].translation.x;
    assert!((coarse - want).abs() > 1e-3, "{coarse} against {want}");
}

#[test]
fn a_lead_poses_the_scene_ahead_of_the_clock() {
    let (scene, b) = sliding_box();
    // The box slides 3 m in 2/3 s: 4.5 m/s.
    let x_at = |t: f32| -1.5 + 4.5 * t;
    let lead = 0.1;
    let mut p = Pipeline::new(
        scene.clone(),
        PipelineConfig {
            lead,
            ..config(Estimator::ClosestHit)
        },
    )
    .unwrap();
    let x = |p: &Pipeline| p.transform(b).unwrap().translation.x;
    assert!((x(&p) - x_at(lead)).abs() < 1e-4, "setup at {}", x(&p));
    p.step(0.2).unwrap();
    assert!((p.time() - 0.2).abs() < 1e-6);
    assert!((p.posed_time() - 0.3).abs() < 1e-6);
    assert!((x(&p) - x_at(0.3)).abs() < 1e-4, "step at {}", x(&p));
    // No lead: the clock's own pose.
    let mut q = Pipeline::new(scene, config(Estimator::ClosestHit)).unwrap();
    q.step(0.2).unwrap();
    assert!((x(&q) - x_at(0.2)).abs() < 1e-4);
    // A lead must be finite, in [0, 1000] s.
    for bad in [-0.1, f32::NAN, f32::INFINITY, 2000.0] {
        let err = Pipeline::new(
            sliding_box().0,
            PipelineConfig {
                lead: bad,
                ..config(Estimator::ClosestHit)
            },
        )
        .unwrap_err();
        assert!(err.to_string().contains("lead"), "{bad}: {err}");
    }
}

/// The sliding box of [`box_error_while_it_moves`] up to the wall and
/// resting there, unbudgeted, with `early` decisions: the rays cast over
/// the run, the worst AO error clients hold on the box against a full
/// trace while it moves, and once it has rested a step; and what the
/// audits found over the run.
fn early_run(early: Option<EarlyDecisions>) -> (u64, f32, f32, EarlyAudit) {
    let (scene, b) = box_by_a_wall();
    let mut c = PipelineConfig {
        density: 256.0,
        early,
        ..config(Estimator::ClosestHit)
    };
    c.ao.rays = 32;
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    let floor = p.points(0).unwrap().len() as u32;
    let (mut rays, mut moving) = (0u64, 0.0f32);
    let mut audit = EarlyAudit::default();
    for t in 0..25 {
        let x = -1.2 + 0.06 * t as f32;
        p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
            .unwrap();
        let (_, r) = p.step(1.0 / 30.0).unwrap();
        rays += r.rays;
        let a = p.early_audit().unwrap();
        assert_eq!(a.checked, r.early, "step {t}");
        audit.checked += a.checked;
        audit.wrong += a.wrong;
        audit.worst_steps = audit.worst_steps.max(a.worst_steps);
        moving = moving.max(worst_held_error(&mut p, b, floor, &ao));
    }
    // It rests: the points that stopped early in its last step are traced
    // again in full.
    let (_, r) = p.step(1.0 / 30.0).unwrap();
    assert_eq!(r.early, 0, "nothing moves, nothing stops early");
    let rested = worst_held_error(&mut p, b, floor, &ao);
    (rays, moving, rested, audit)
}

#[test]
fn early_decisions_cast_fewer_rays_and_stay_near_a_full_trace() {
    let (full_rays, full_moving, full_rested, none) = early_run(None);
    assert_eq!(
        none,
        EarlyAudit::default(),
        "no early decisions, nothing to audit"
    );
    let (rays, moving, rested, audit) = early_run(Some(EarlyDecisions::default()));
    assert!(audit.checked > 0, "points stopped early");
    assert!(
        rays * 10 < full_rays * 9,
        "{rays} rays against {full_rays} without early decisions"
    );
    // The defaults' test, on this box: a wrong decision is rare (at most
    // one in a thousand), and what it leaves behind is near the send
    // threshold (within twice it), not a lost update.
    assert!(audit.wrong * 1000 <= audit.checked, "{audit:?}");
    assert!(audit.worst_steps <= 16, "{audit:?}");
    assert!(
        moving <= 16.5 / 255.0,
        "box AO off by {} steps",
        moving * 255.0
    );
    assert!(full_moving <= 8.5 / 255.0 && full_rested <= 8.5 / 255.0);
    // Once it rests, clients hold a full trace, to the send threshold.
    assert!(rested <= 8.5 / 255.0, "{}", rested * 255.0);
}

#[test]
fn a_reckless_early_test_is_caught_by_the_audit_and_undone_when_motion_stops() {
    // No margin at all: a point stops as soon as its estimate alone lies
    // within the threshold, so some decisions go wrong, and the audit
    // says so; the box resting, they are traced again in full.
    let reckless = EarlyDecisions {
        z: 0.0,
        sd_floor: 0.0,
        sd_floor_turning: 0.0,
        ..EarlyDecisions::default()
    };
    let (_, moving, rested, audit) = early_run(Some(reckless));
    assert!(audit.wrong > 0, "{audit:?}");
    assert!(audit.worst_steps > 8, "{audit:?}");
    assert!(moving > 8.5 / 255.0, "{}", moving * 255.0);
    assert!(
        rested <= 8.5 / 255.0,
        "after the box rests: {}",
        rested * 255.0
    );
}

#[test]
fn bad_early_settings_are_refused_by_name() {
    for (early, name) in [
        (
            EarlyDecisions {
                z: f32::NAN,
                ..EarlyDecisions::default()
            },
            "early.z",
        ),
        (
            EarlyDecisions {
                sd_floor: -0.1,
                ..EarlyDecisions::default()
            },
            "early.sd_floor",
        ),
        (
            EarlyDecisions {
                sd_floor_turning: 2.0,
                ..EarlyDecisions::default()
            },
            "early.sd_floor_turning",
        ),
    ] {
        let c = PipelineConfig {
            early: Some(early),
            ..config(Estimator::ClosestHit)
        };
        let e = Pipeline::new(sliding_box().0, c).unwrap_err().to_string();
        assert!(e.contains(name), "{e}");
    }
}

#[test]
fn a_wait_limit_below_max_wait_is_refused_by_name() {
    let c = PipelineConfig {
        budget: RayBudget::Rays(100),
        max_wait: 8,
        max_wait_limit: 4,
        ..config(Estimator::ClosestHit)
    };
    let e = Pipeline::new(sliding_box().0, c).unwrap_err().to_string();
    assert!(e.contains("max_wait_limit"), "{e}");
}

/// Rays cast and points sent over `ticks` steps of 1/60 s of the default
/// scene (the stream example's step), 32 rays a point.
fn default_scene_run(ray_reuse: bool, budget: RayBudget, ticks: u32) -> (u64, u64) {
    let c = PipelineConfig {
        density: 256.0,
        ray_reuse,
        budget,
        ao: AoParams {
            rays: 32,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let mut p = Pipeline::new(default_scene(), c).unwrap();
    let (mut rays, mut sent) = (0, 0);
    for _ in 0..ticks {
        let (_, r) = p.step(1.0 / 60.0).unwrap();
        rays += r.rays;
        sent += r.updated;
    }
    (rays, sent)
}

#[test]
fn a_quarter_of_a_full_retrace_sends_nearly_every_point_it_sends() {
    // Issue 20: rays at a quarter of a full re-trace's, at equal points
    // sent. The budget goes where a ray is likeliest to send (each
    // point's trend): the points left waiting are mostly those whose AO
    // would have stayed within the threshold anyway.
    let ticks = 60;
    let (full, _) = default_scene_run(false, RayBudget::Unlimited, ticks);
    let (_, sent) = default_scene_run(true, RayBudget::Unlimited, ticks);
    let quarter = full / ticks as u64 / 4;
    let (rays, budgeted) = default_scene_run(true, RayBudget::Rays(quarter), ticks);
    assert!(sent > 0 && rays > 0);
    // Points that came due go past the budget: at most a few.
    assert!(
        rays <= full / 4 + full / 40,
        "{rays} rays against a full re-trace's {full}"
    );
    assert!(
        budgeted * 10 >= sent * 9,
        "{budgeted} points sent under a quarter of the rays against {sent} unbudgeted"
    );
}

/// A bar rising out of a well (an open box on a floor), 0.04 m a step,
/// under a budget of two fifths of what the bar's points need: the rim
/// sweeps down the bar, turning each point from dark to open in turn.
/// Returns the mean AO error clients hold on the bar's points that came
/// out of the well between 2 and 6 steps before (their AO jumped then),
/// over the steps the bar rises.
fn bar_out_of_a_well_error() -> f32 {
    let mut s = Scene::default();
    s.add(
        Mesh::quad(Vec3::new(-1.0, 0.0, -1.0), Vec3::Z * 2.0, Vec3::X * 2.0).subdivided(2),
        Affine3A::IDENTITY,
    );
    // The well: four walls 0.8 m high round a 0.5 m square.
    let (h, w) = (0.8, 0.25);
    for (corner, along) in [
        (Vec3::new(-w, 0.0, -w), Vec3::X * 2.0 * w),
        (Vec3::new(w, 0.0, -w), Vec3::Z * 2.0 * w),
        (Vec3::new(w, 0.0, w), Vec3::X * -2.0 * w),
        (Vec3::new(-w, 0.0, w), Vec3::Z * -2.0 * w),
    ] {
        s.add(Mesh::quad(corner, Vec3::Y * h, along), Affine3A::IDENTITY);
    }
    let node = s.add_node("bar", None, Trs::default());
    let bar = s.add_on_node(
        Mesh::cuboid(Vec3::new(-0.15, 0.0, -0.15), Vec3::new(0.15, h, 0.15)),
        node,
    );
    s.animations.push(Animation::translation(
        "rise",
        node,
        &[(0.0, Vec3::ZERO), (2.0 / 3.0, Vec3::Y * h)],
    ));
    let c = PipelineConfig {
        density: 256.0,
        max_wait: 8,
        max_wait_limit: 8,
        ao: AoParams {
            rays: 24,
            radius: 0.3,
            estimator: Estimator::ClosestHit,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let ao = c.ao;
    let p = Pipeline::new(s.clone(), c.clone()).unwrap();
    let bar_points = p.points(bar).unwrap().len() as u64;
    let base: u32 = (0..bar).map(|i| p.points(i).unwrap().len() as u32).sum();
    drop(p);
    let budget = bar_points * ao.rays as u64 * 2 / 5;
    let mut p = Pipeline::new(
        s,
        PipelineConfig {
            budget: RayBudget::Rays(budget),
            ..c
        },
    )
    .unwrap();
    let local: Vec<Vec3> = p.points(bar).unwrap().positions.clone();
    let (mut sum, mut n) = (0.0f32, 0u32);
    for t in 1..=20 {
        let rise = 0.04 * t as f32;
        p.place_instance(bar, Affine3A::from_translation(Vec3::Y * rise))
            .unwrap();
        p.step(1.0 / 30.0).unwrap();
        let tracer = p.current_tracer();
        let (pos, nrm) = p.current_points(bar).unwrap();
        let world: Vec<Vec3> = pos.iter().map(|&q| q + Vec3::Y * rise).collect();
        let ids: Vec<u32> = (0..pos.len() as u32).map(|k| base + k).collect();
        let fresh = tracer.trace_ids(&ids, &world, nrm, &ao).unwrap();
        let table = p.table(bar).unwrap();
        for (k, q) in local.iter().enumerate() {
            // Came out of the well 2 to 6 steps ago, on the bar's sides.
            let out = q.y + rise - h;
            if !(0.08..=0.24).contains(&out) || q.y > h - 0.01 {
                continue;
            }
            if let psao_codec::Placement::Stored { cell, slot } = table.placement(k as u32) {
                sum += (PointWord(table.cell(cell)[slot as usize]).ao() - fresh.ao[k]).abs();
                n += 1;
            }
        }
    }
    assert!(n > 0, "no point came out");
    sum / n as f32
}

#[test]
fn points_near_a_sweeping_change_are_traced_before_the_rest_waits() {
    // The bar's points trace about once in two or three steps, those
    // near the rim first (where their neighbours' AO just jumped: the
    // `Heat` of the pipeline's `trend`): what clients hold of them is
    // within 5.5 steps of 1/255 of a full trace on average. Measured with
    // the Fibonacci ray lattice of `PointRays::ray` and points that come
    // out open sent: 5.2 steps; with local patches, 5.8 with the points
    // ranked by their own trends alone (no heat) and 1.5 with no budget.
    // (With azimuths drawn at random per ray, when this was written: 5.2,
    // 7.1 and 2.1; with the lattice before open points were sent, 6.2,
    // 7.2 and 3.0. So heat's gain in this test fell from 1.9 steps to
    // 0.6, and the bound is close on both sides.)
    let err = bar_out_of_a_well_error();
    assert!(err <= 5.5 / 255.0, "off by {} steps", err * 255.0);
}

/// The frames of the box by a wall, pushed back and forth for 40 steps,
/// with early decisions under `budget`, with its points known open and
/// early stops, and per step the rays cast and those the points known
/// open did not cast.
type KnownOpenRun = (Vec<Option<Vec<u8>>>, u64, u64, Vec<(u64, u64)>);

/// [`KnownOpenRun`], points known open or not (`skip_open`).
fn known_open_run(skip_open: bool, budget: RayBudget) -> KnownOpenRun {
    let (scene, b) = box_by_a_wall();
    let mut c = PipelineConfig {
        density: 128.0,
        early: Some(EarlyDecisions::default()),
        budget,
        skip_open,
        ..PipelineConfig::default()
    };
    c.ao.rays = 32;
    let mut p = Pipeline::new(scene, c).unwrap();
    let (mut frames, mut open, mut early) = (Vec::new(), 0, 0);
    let mut rays = Vec::new();
    for t in 0..40 {
        let x = -1.2 + 0.06 * (t % 30) as f32;
        p.place_instance(b, Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)))
            .unwrap();
        let (f, r) = p.step(1.0 / 30.0).unwrap();
        frames.push(f.map(|f| f.bytes.to_vec()));
        open += r.open;
        early += r.early;
        rays.push((r.rays, r.rays_open));
    }
    (frames, open, early, rays)
}

#[test]
fn points_known_open_decide_early_as_their_rays_would() {
    // A moving point known open takes its early decision on scores of 1,
    // what its rays would give: the same stops, the same price for the
    // budget, the same frames.
    for budget in [
        RayBudget::Unlimited,
        RayBudget::Rays(3000),
        RayBudget::Rays(8000),
    ] {
        let (frames, open, early, rays) = known_open_run(true, budget);
        let (frames_cast, none, early_cast, rays_cast) = known_open_run(false, budget);
        assert!(open > 0 && none == 0, "{budget:?}: {open}");
        // Each step, the rays the open points did not cast are those the
        // same points cast when not known open: what the budget paid for.
        assert!(rays.iter().any(|r| r.1 > 0), "{budget:?}");
        for (t, (&(cast, uncast), &(all, none))) in rays.iter().zip(&rays_cast).enumerate() {
            assert_eq!(none, 0, "{budget:?}, step {t}");
            assert_eq!(cast + uncast, all, "{budget:?}, step {t}");
        }
        assert_eq!(early, early_cast, "{budget:?}: early stops");
        let first = frames.iter().zip(&frames_cast).position(|(a, b)| a != b);
        assert_eq!(first, None, "{budget:?}: first frame that differs");
    }
}

/// [`box_by_a_wall`] under a budget of `rays` a step for six rounds of
/// its loop (2/3 s, 20 steps of 1/30 s) with the loop memory capped at
/// `loop_memory_bytes`: per step of the last three rounds, the points of
/// every instance whose held AO lies more than the send threshold from a
/// full trace; and the points the memory holds.
fn looping_box_run(rays: u64, loop_memory_bytes: u64) -> (Vec<usize>, usize) {
    let (scene, _) = box_by_a_wall();
    assert_eq!(scene.loop_period(20.0), Some(2.0 / 3.0));
    let c = PipelineConfig {
        budget: RayBudget::Rays(rays),
        max_wait: 8,
        movers_whole: MoversWhole::Off,
        loop_memory_bytes,
        ..config(Estimator::ClosestHit)
    };
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    let mut off = Vec::new();
    for t in 0..6 * 20 {
        p.step(1.0 / 30.0).unwrap();
        if t >= 3 * 20 {
            off.push(held_off(&mut p, &ao).into_iter().filter(|&o| o).count());
        }
    }
    (off, p.loop_memory().map_or(0, |(_, points, _)| points))
}

#[test]
fn the_loop_memory_leaves_fewer_points_off_a_full_trace() {
    // Without the memory, a point's trend is all the budget knows; with
    // it, whether the AO it had at this moment of an earlier round would
    // be sent. Under demand beyond the budget (240 rays a step, the bound
    // on waiting rises) and within it (960).
    for (rays, most) in [(240, 0.95), (960, 0.5)] {
        let (without, none) = looping_box_run(rays, 0);
        let (with, remembered) = looping_box_run(rays, 64 << 20);
        assert_eq!(none, 0);
        assert!(remembered > 0);
        let (a, b): (usize, usize) = (without.iter().sum(), with.iter().sum());
        assert!(
            (b as f64) < most * a as f64,
            "{rays} rays a step: points off a full trace past the threshold over three rounds, {b} with the memory against {a} without ({with:?} against {without:?})"
        );
    }
}

#[test]
fn the_loop_memory_is_kept_only_under_a_budget_in_a_scene_that_loops() {
    let (scene, b) = box_by_a_wall();
    let under = |budget, bytes| PipelineConfig {
        budget,
        loop_memory_bytes: bytes,
        ..config(Estimator::ClosestHit)
    };
    let memory = |scene: &Scene, c| {
        let mut p = Pipeline::new(scene.clone(), c).unwrap();
        for _ in 0..25 {
            p.step(1.0 / 30.0).unwrap();
        }
        p.loop_memory()
    };
    let (period, points, bytes) = memory(&scene, under(RayBudget::Rays(96), 64 << 20)).unwrap();
    assert!((period - 2.0 / 3.0).abs() < 1e-6);
    assert!(points > 0 && bytes > 0);
    assert_eq!(memory(&scene, under(RayBudget::Unlimited, 64 << 20)), None);
    assert_eq!(memory(&scene, under(RayBudget::Rays(96), 0)), None);
    // A scene that does not move has no loop.
    let mut still = scene.clone();
    still.animations.clear();
    assert_eq!(memory(&still, under(RayBudget::Rays(96), 64 << 20)), None);
    // A part placed by hand breaks the loop.
    let mut p = Pipeline::new(scene, under(RayBudget::Rays(96), 64 << 20)).unwrap();
    p.step(1.0 / 30.0).unwrap();
    let with = p.memory_bytes();
    assert!(p.loop_memory().is_some());
    p.place_instance(b, Affine3A::from_translation(Vec3::X))
        .unwrap();
    assert_eq!(p.loop_memory(), None);
    assert!(p.memory_bytes() <= with);
}

/// Every frame's bytes of RiggedSimple (a skinned cylinder bending in a
/// loop of 2.083 s, nothing else) over 200 steps of 1/60 s under a budget,
/// its points stored in bind space or as posed, with the loop memory on or
/// off; and whether the memory was kept.
fn rigged_frames(bind_space: bool, loop_memory_bytes: u64) -> (Vec<Vec<u8>>, bool) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/RiggedSimple.glb");
    let scene = load_gltf(&path).unwrap();
    let c = PipelineConfig {
        density: 64.0,
        ao: AoParams {
            rays: 16,
            ..AoParams::default()
        },
        budget: RayBudget::Rays(64),
        bind_space,
        loop_memory_bytes,
        ..PipelineConfig::default()
    };
    let mut p = Pipeline::new(scene, c).unwrap();
    let mut frames = vec![p.keyframe().unwrap().bytes.to_vec()];
    for _ in 0..200 {
        let (f, _) = p.step(1.0 / 60.0).unwrap();
        frames.push(f.map(|f| f.bytes.to_vec()).unwrap_or_default());
    }
    (frames, p.loop_memory().is_some())
}

#[test]
fn the_loop_memory_leaves_points_stored_as_posed_to_their_trends() {
    // In bind space a deforming point never moves where clients hold it,
    // so the memory may rank it (the frames change once a loop has
    // passed); stored as posed, its position alone may send it, and the
    // memory leaves it to its trend: the same frames as without.
    let (bind_on, kept) = rigged_frames(true, 64 << 20);
    let (bind_off, none) = rigged_frames(true, 0);
    assert!(kept && !none);
    assert!(
        bind_on != bind_off,
        "the memory changed nothing in bind space"
    );
    let (posed_on, kept) = rigged_frames(false, 64 << 20);
    let (posed_off, _) = rigged_frames(false, 0);
    assert!(kept);
    assert!(
        posed_on == posed_off,
        "the memory changed frames of points stored as posed"
    );
}

/// The steps, of the 60 in which [`turning_cross`] turns (at 30 Hz), in
/// which the transform clients hold of its first bar did not move, under
/// a budget a bar's points cost 1.5 times, held whole as `movers_whole`
/// says.
fn cross_held_steps(movers_whole: MoversWhole) -> usize {
    let scene = turning_cross();
    let bar = 2;
    let mut c = PipelineConfig {
        max_wait: 6,
        movers_whole,
        ..config(Estimator::ClosestHit)
    };
    let p = Pipeline::new(scene.clone(), c.clone()).unwrap();
    let n = p.points(bar).unwrap().len() as u64;
    c.budget = RayBudget::Rays(n * u64::from(c.ao.rays) * 2 / 3);
    let mut p = Pipeline::new(scene, c).unwrap();
    let id = p.table(bar).unwrap().id();
    let mut client = psao_codec::Decoder::new(psao_codec::Limits::default());
    client.receive(&p.keyframe().unwrap().bytes).unwrap();
    let held = |c: &psao_codec::Decoder| c.mirror().instance(id).unwrap().transform().cloned();
    let mut still = 0;
    for _ in 0..60 {
        let before = held(&client);
        let (f, _) = p.step(1.0 / 30.0).unwrap();
        if let Some(f) = f {
            client.receive(&f.bytes).unwrap();
        }
        still += usize::from(held(&client) == before);
    }
    still
}

#[test]
fn auto_does_not_hold_a_part_turning_in_place() {
    // A part turning about its own centre by a block changes its own AO
    // as it turns (as a wheel in its arch does), but it stays where it
    // is: its AO pattern stays with its surroundings, and a transform held
    // back would turn that pattern with the part. `Auto` sends its
    // transform every step it turns, where `On` holds it.
    assert_eq!(cross_held_steps(MoversWhole::Auto), 0);
    assert_eq!(cross_held_steps(MoversWhole::Off), 0);
    assert!(cross_held_steps(MoversWhole::On) > 0);
}

/// [`box_by_a_wall`] over twelve rounds of its loop (40 steps of 1/60 s
/// each) under a budget of `rays` a step, its box held whole or not
/// (`whole`), the loop memory verifying waiting points or not
/// (`loop_verify`): the points verified and those
/// traced overdue over the run, the longest any point's held AO stayed
/// more than the send threshold from a full trace of the scene as posed
/// (steps in a row), the largest bound on waiting in force, and the
/// points so held summed over the steps.
fn verify_run(rays: u64, whole: MoversWhole, loop_verify: bool) -> (u64, u64, u32, u32, usize) {
    let (scene, _) = box_by_a_wall();
    let c = PipelineConfig {
        budget: RayBudget::Rays(rays),
        movers_whole: whole,
        loop_verify,
        ..config(Estimator::ClosestHit)
    };
    let ao = c.ao;
    let mut p = Pipeline::new(scene, c).unwrap();
    let mut streak = Vec::new();
    let (mut verified, mut overdue, mut longest, mut bound) = (0, 0, 0, 0);
    let mut off_steps = 0;
    for _ in 0..12 * 40 {
        let (_, r) = p.step(1.0 / 60.0).unwrap();
        verified += r.verified;
        overdue += r.overdue;
        bound = bound.max(r.wait_bound);
        let off = held_off(&mut p, &ao);
        streak.resize(off.len(), 0u32);
        for (s, off) in streak.iter_mut().zip(off) {
            *s = if off { *s + 1 } else { 0 };
            longest = longest.max(*s);
            off_steps += usize::from(off);
        }
    }
    (verified, overdue, longest, bound, off_steps)
}

#[test]
fn the_loop_memory_verifies_waiting_points_and_no_point_lags_past_the_bound() {
    // The box slides along the wall and jumps back at the loop's start.
    // Points it keeps reaching without changing them wait; where one's AO
    // traced at the same time of an earlier round would not be sent, its
    // wait starts again instead of its being traced when due. Clients
    // still never lag a full re-trace past the bound: a point whose held
    // AO is off is not verified (a wrong verification, across the box's
    // jump or far from the time it was traced at, would keep a point off
    // for good).
    for (rays, whole) in [
        (240, MoversWhole::Off),
        (960, MoversWhole::Off),
        (240, MoversWhole::Auto),
    ] {
        let (verified, overdue, longest, bound, off) = verify_run(rays, whole, true);
        let (none, overdue_plain, longest_plain, bound_plain, off_plain) =
            verify_run(rays, whole, false);
        eprintln!(
            "{rays} rays a step, {whole:?}: verified {verified} (off: {none}), overdue {overdue} against {overdue_plain}, held off a full trace at most {longest} steps against {longest_plain}, bound {bound} against {bound_plain}, {off} points held off over the steps against {off_plain}"
        );
        assert!(verified > 0 && none == 0, "{rays}: {verified} verified");
        assert!(
            overdue < overdue_plain,
            "{rays}: {overdue} overdue with verifying against {overdue_plain} without"
        );
        assert!(
            longest <= bound,
            "{rays}: held off for {longest} steps, bound {bound}"
        );
        assert!(
            longest_plain <= bound_plain,
            "{rays}: {longest_plain} > {bound_plain}"
        );
    }
}
