//! Node animation, the hierarchy, skinning against known poses, and camera
//! paths.

use std::f32::consts::{FRAC_PI_2, PI};
use std::path::Path;

use glam::{Affine3A, Quat, Vec3};
use psao_scene::*;

fn close(a: Vec3, b: Vec3, eps: f32) -> bool {
    (a - b).abs().max_element() <= eps
}

fn channel(keys: Keys, times: &[f32], interpolation: Interpolation) -> Channel {
    Channel {
        node: 0,
        times: times.to_vec(),
        keys,
        interpolation,
    }
}

#[test]
fn channels_interpolate_step_linear_slerp_and_cubic() {
    let mut trs = Trs::default();
    let t = |c: &Channel, time: f32, trs: &mut Trs| {
        c.apply(time, trs);
        trs.translation
    };
    let keys = Keys::Translation(vec![Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0)]);
    let linear = channel(keys.clone(), &[1.0, 2.0], Interpolation::Linear);
    assert_eq!(
        t(&linear, 0.0, &mut trs),
        Vec3::ZERO,
        "before the first key"
    );
    assert_eq!(t(&linear, 1.25, &mut trs), Vec3::new(0.5, 0.0, 0.0));
    assert_eq!(t(&linear, 9.0, &mut trs), Vec3::new(2.0, 0.0, 0.0), "after");
    let step = channel(keys, &[1.0, 2.0], Interpolation::Step);
    assert_eq!(t(&step, 1.99, &mut trs), Vec3::ZERO);
    assert_eq!(t(&step, 2.0, &mut trs), Vec3::new(2.0, 0.0, 0.0));
    // Slerp: halfway between 0 and 90 degrees about y is 45 degrees (a
    // linear blend of the quaternions would give the same axis but the
    // check below is on the exact angle at a quarter).
    let rot = channel(
        Keys::Rotation(vec![Quat::IDENTITY, Quat::from_rotation_y(FRAC_PI_2)]),
        &[0.0, 1.0],
        Interpolation::Linear,
    );
    rot.apply(0.25, &mut trs);
    let expect = Quat::from_rotation_y(FRAC_PI_2 * 0.25);
    assert!(trs.rotation.angle_between(expect) < 1e-5);
    // Shortest arc: from 170 to -170 degrees goes through 180, not 0.
    let wrap = channel(
        Keys::Rotation(vec![
            Quat::from_rotation_y(170f32.to_radians()),
            Quat::from_rotation_y(-170f32.to_radians()),
        ]),
        &[0.0, 1.0],
        Interpolation::Linear,
    );
    wrap.apply(0.5, &mut trs);
    assert!(trs.rotation.angle_between(Quat::from_rotation_y(PI)) < 1e-4);
    // Cubic spline with zero tangents eases: at s = 0.5 it is halfway, at
    // s = 0.25 it is below linear (Hermite h = 3s^2 - 2s^3 = 0.15625).
    let z = Vec3::ZERO;
    let cubic = channel(
        Keys::Translation(vec![z, Vec3::ZERO, z, z, Vec3::X * 4.0, z]),
        &[0.0, 2.0],
        Interpolation::CubicSpline,
    );
    assert!(close(t(&cubic, 1.0, &mut trs), Vec3::X * 2.0, 1e-6));
    assert!(close(t(&cubic, 0.5, &mut trs), Vec3::X * 0.625, 1e-6));
    // With tangents: p(s) for p0 = 0, m0 = 1 per second, p1 = 0, m1 = 0 over
    // 2 s is (s^3 - 2s^2 + s) * 2.
    let tangent = channel(
        Keys::Translation(vec![z, z, Vec3::X, z, z, z]),
        &[0.0, 2.0],
        Interpolation::CubicSpline,
    );
    let s = 0.5f32;
    let want = (s * s * s - 2.0 * s * s + s) * 2.0;
    assert!(close(t(&tangent, 1.0, &mut trs), Vec3::X * want, 1e-6));
}

#[test]
fn weight_channels_interpolate_every_target_and_are_validated() {
    let keys = |values: Vec<f32>| Keys::Weights { targets: 2, values };
    let mut w = Vec::new();
    // Linear: each target on its own; clamped outside the keys.
    let c = channel(
        keys(vec![0.0, 1.0, 1.0, 0.0]),
        &[0.0, 2.0],
        Interpolation::Linear,
    );
    c.validate(1, 0, 0).unwrap();
    c.weights(0.5, &mut w);
    assert_eq!(w, vec![0.25, 0.75]);
    c.weights(9.0, &mut w);
    assert_eq!(w, vec![1.0, 0.0]);
    // Step holds the key at or before the time.
    let c = channel(
        keys(vec![0.0, 1.0, 1.0, 0.0]),
        &[0.0, 2.0],
        Interpolation::Step,
    );
    c.weights(1.9, &mut w);
    assert_eq!(w, vec![0.0, 1.0]);
    // Cubic spline with zero tangents: smoothstep between the values, and
    // the values themselves at the keys.
    let c = channel(
        keys(vec![
            0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0, 1.0, 8.0, 0.0, 0.0,
        ]),
        &[0.0, 1.0],
        Interpolation::CubicSpline,
    );
    c.validate(1, 0, 0).unwrap();
    c.weights(0.0, &mut w);
    assert_eq!(w, vec![0.0, 4.0]);
    c.weights(0.5, &mut w);
    assert!(
        (w[0] - 0.5).abs() < 1e-6 && (w[1] - 6.0).abs() < 1e-6,
        "{w:?}"
    );
    // A weights channel leaves the node's transform alone, and a
    // translation channel leaves weights alone.
    let mut trs = Trs::default();
    c.apply(0.5, &mut trs);
    assert_eq!(trs, Trs::default());
    let mut w = vec![7.0];
    channel(
        Keys::Translation(vec![Vec3::X]),
        &[0.0],
        Interpolation::Step,
    )
    .weights(0.0, &mut w);
    assert_eq!(w, vec![7.0]);
    // Counts that are no whole number of keys of `targets`, or no targets.
    for (k, why) in [
        (keys(vec![0.0, 1.0, 2.0]), "whole number"),
        (
            Keys::Weights {
                targets: 0,
                values: vec![],
            },
            "whole number",
        ),
        (keys(vec![0.0, 1.0]), "values for 2 keys"),
    ] {
        let e = channel(k, &[0.0, 1.0], Interpolation::Linear)
            .validate(1, 0, 0)
            .unwrap_err();
        assert!(e.to_string().contains(why), "{e}");
    }
}

#[test]
fn morph_targets_blend_from_the_rest_weights() {
    let t = MorphTargets {
        rest_weights: vec![0.5, 0.0],
        positions: vec![vec![Vec3::Y, Vec3::Y], vec![]],
        normals: vec![vec![], vec![Vec3::X, Vec3::ZERO]],
    };
    t.check(2).unwrap();
    let (p, n) = (vec![Vec3::ZERO, Vec3::X], vec![Vec3::Z, Vec3::Z]);
    let (mut op, mut on) = (Vec::new(), Vec::new());
    t.apply(&[1.0, 1.0], &p, &n, &mut op, &mut on);
    assert_eq!(op, vec![Vec3::Y * 0.5, Vec3::X + Vec3::Y * 0.5]);
    assert!(close(on[0], Vec3::new(1.0, 0.0, 1.0).normalize(), 1e-6));
    assert_eq!(on[1], Vec3::Z);
    // The rest weights give the rest mesh back; missing weights are rest.
    t.apply(&[0.5], &p, &n, &mut op, &mut on);
    assert_eq!((op.clone(), on.clone()), (p.clone(), n.clone()));
    // A normal that cancels out keeps its rest direction.
    let flip = MorphTargets {
        rest_weights: vec![0.0],
        positions: vec![vec![]],
        normals: vec![vec![-Vec3::Z, -Vec3::Z]],
    };
    flip.apply(&[1.0], &p, &n, &mut op, &mut on);
    assert_eq!(on, n);
    // Checked: offsets per vertex, finite, one list per target.
    for (bad, why) in [
        (
            MorphTargets {
                positions: vec![vec![Vec3::Y]],
                ..flip.clone()
            },
            "1 position offsets for 2",
        ),
        (
            MorphTargets {
                normals: vec![],
                ..flip.clone()
            },
            "normal offset lists",
        ),
        (
            MorphTargets {
                rest_weights: vec![f32::NAN],
                ..flip.clone()
            },
            "rest weight 0",
        ),
        (
            MorphTargets {
                positions: vec![vec![Vec3::NAN, Vec3::Y]],
                ..flip.clone()
            },
            "not finite",
        ),
    ] {
        let e = bad.check(2).unwrap_err();
        assert!(e.contains(why), "{e}");
    }
}

#[test]
fn channels_are_validated() {
    let good = channel(
        Keys::Translation(vec![Vec3::ZERO, Vec3::X]),
        &[0.0, 1.0],
        Interpolation::Linear,
    );
    assert!(good.validate(1, 0, 0).is_ok());
    let bad = |c: Channel, why: &str| {
        let e = c.validate(1, 3, 4).unwrap_err();
        assert!(
            matches!(e, SceneError::Animation { animation: 3, channel: 4, ref reason } if reason.contains(why)),
            "{e}"
        );
    };
    bad(
        Channel {
            node: 1,
            ..good.clone()
        },
        "drives node 1 of 1",
    );
    bad(
        Channel {
            times: vec![],
            ..good.clone()
        },
        "no keys",
    );
    bad(
        Channel {
            times: vec![1.0, 1.0],
            ..good.clone()
        },
        "strictly increasing",
    );
    bad(
        Channel {
            times: vec![-1.0, 1.0],
            ..good.clone()
        },
        "negative",
    );
    bad(
        Channel {
            times: vec![0.0, f32::NAN],
            ..good.clone()
        },
        "not finite",
    );
    bad(
        Channel {
            times: vec![0.0],
            ..good.clone()
        },
        "2 values for 1 keys",
    );
    bad(
        Channel {
            interpolation: Interpolation::CubicSpline,
            ..good.clone()
        },
        "3 per key",
    );
    bad(
        Channel {
            keys: Keys::Translation(vec![Vec3::ZERO, Vec3::NAN]),
            ..good.clone()
        },
        "not finite",
    );
    bad(
        Channel {
            keys: Keys::Rotation(vec![Quat::IDENTITY, Quat::from_xyzw(0.0, 0.0, 0.0, 2.0)]),
            ..good
        },
        "unit quaternion",
    );
}

#[test]
fn animations_loop_over_their_duration() {
    let a = Animation::translation("a", 0, &[(0.0, Vec3::ZERO), (2.0, Vec3::X * 2.0)]);
    assert_eq!(a.duration(), 2.0);
    assert_eq!(a.local_time(5.0), 1.0);
    assert_eq!(a.local_time(-0.5), 1.5);
    assert_eq!(a.local_time(f32::NAN), 0.0);
    let mut nodes = vec![Trs::default()];
    a.apply(4.5, &mut nodes);
    assert_eq!(nodes[0].translation, Vec3::X * 0.5);
}

#[test]
fn the_hierarchy_composes_parents_first_and_is_validated() {
    let mut s = Scene::default();
    let root = s.add_node(
        "root",
        None,
        Trs {
            translation: Vec3::X,
            rotation: Quat::from_rotation_z(FRAC_PI_2),
            scale: Vec3::splat(2.0),
        },
    );
    let child = s.add_node("child", Some(root), Trs::from_translation(Vec3::X));
    let i = s.add_on_node(Mesh::quad(Vec3::ZERO, Vec3::X, Vec3::Z), child);
    assert!(s.validate().is_ok());
    let pose = s.pose(0.0);
    // child's origin: root maps (1,0,0) -> rotate 90 about z, scale 2 ->
    // (0,2,0), then + (1,0,0).
    assert!(close(
        pose.nodes[child].transform_point3(Vec3::ZERO),
        Vec3::new(1.0, 2.0, 0.0),
        1e-6
    ));
    assert_eq!(pose.instances[i], pose.nodes[child]);
    // A parent after its child is refused, as is a node index past the end.
    let mut bad = s.clone();
    bad.nodes[root].parent = Some(child);
    assert!(
        matches!(bad.validate(), Err(SceneError::Element { ref element, .. }) if element.starts_with("node 0"))
    );
    let mut bad = s.clone();
    bad.instances[i].node = Some(7);
    assert!(
        matches!(bad.validate(), Err(SceneError::Element { ref reason, .. }) if reason.contains("node 7 of 2"))
    );
    // Only what an animation drives is dynamic (children included).
    assert_eq!(s.dynamic_instances(), vec![false]);
    s.animations.push(Animation::translation(
        "move",
        root,
        &[(0.0, Vec3::ZERO), (1.0, Vec3::Y)],
    ));
    assert_eq!(s.dynamic_instances(), vec![true]);
    // An animation that scales to zero makes the pose invalid: validation
    // of the pose at time 0 refuses it.
    s.animations.push(Animation {
        name: "vanish".into(),
        channels: vec![Channel {
            node: child,
            times: vec![0.0],
            keys: Keys::Scale(vec![Vec3::ZERO]),
            interpolation: Interpolation::Step,
        }],
    });
    assert!(matches!(
        s.validate(),
        Err(SceneError::BadTransform { instance: 0 })
    ));
}

/// Two joints: joint 0 at the origin, joint 1 at (1, 0, 0) turned 90
/// degrees about z. A vertex at (2, 0, 0) bound fully to joint 1 swings to
/// (1, 1, 0); bound half and half it lands midway, (1.5, 0.5, 0).
#[test]
fn linear_blend_skinning_matches_a_hand_computed_pose() {
    let mut s = Scene::default();
    let j0 = s.add_node("j0", None, Trs::default());
    let j1 = s.add_node("j1", Some(j0), Trs::from_translation(Vec3::X));
    s.skins.push(Skin {
        name: "arm".into(),
        joints: vec![j0, j1],
        // Bind pose: j0 at the origin, j1 at (1, 0, 0).
        inverse_bind: vec![Affine3A::IDENTITY, Affine3A::from_translation(-Vec3::X)],
    });
    let mut mesh = Mesh::quad(Vec3::ZERO, Vec3::X * 2.0, Vec3::Z);
    // Corners: (0,0,0), (2,0,0), (2,0,1), (0,0,1).
    mesh.skin = Some(SkinWeights {
        joints: vec![[0, 1, 0, 0]; 4],
        weights: vec![
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.5, 0.5, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
        ],
    });
    let i = s.add(mesh, Affine3A::IDENTITY);
    s.instances[i].skin = Some(0);
    s.animations.push(Animation {
        name: "bend".into(),
        channels: vec![Channel {
            node: j1,
            times: vec![0.0, 1.0, 2.0],
            keys: Keys::Rotation(vec![
                Quat::IDENTITY,
                Quat::from_rotation_z(FRAC_PI_2),
                Quat::IDENTITY,
            ]),
            interpolation: Interpolation::Linear,
        }],
    });
    assert!(s.validate().is_ok());
    let rest = s.pose(0.0);
    let (p, _) = s.deformed(i, &rest);
    assert_eq!(
        &p[..],
        &s.meshes[0].positions[..],
        "the bind pose is the rest pose"
    );
    let bent = s.pose(1.0);
    let (p, n) = s.deformed(i, &bent);
    assert!(close(p[0], Vec3::ZERO, 1e-6), "bound to the still joint");
    assert!(close(p[1], Vec3::new(1.0, 1.0, 0.0), 1e-6), "{}", p[1]);
    assert!(close(p[2], Vec3::new(1.5, 0.5, 1.0), 1e-6), "{}", p[2]);
    assert_eq!(p[3], Vec3::new(0.0, 0.0, 1.0), "no weight: stays put");
    // The normal (-y for this quad, X x Z) turns with joint 1: (1, 0, 0).
    assert_eq!(s.meshes[0].normals[1], -Vec3::Y);
    assert!(close(n[1], Vec3::X, 1e-6), "{}", n[1]);
    // Points ride along: a point at the middle of the far edge follows it.
    let pts = generate_points(&s.meshes[0], 400.0, 3).unwrap();
    let (mut fp, mut fnrm) = (Vec::new(), Vec::new());
    pts.follow(&s.meshes[0], &p, &n, &mut fp, &mut fnrm);
    assert_eq!(fp.len(), pts.len());
    let (mut rp, mut rn) = (Vec::new(), Vec::new());
    let rest_pos = s.meshes[0].positions.clone();
    let rest_nrm = s.meshes[0].normals.clone();
    pts.follow(&s.meshes[0], &rest_pos, &rest_nrm, &mut rp, &mut rn);
    for (k, (a, b)) in rp.iter().zip(&pts.positions).enumerate() {
        assert!(close(*a, *b, 1e-5), "anchors reproduce point {k}");
    }
    // Skin weights are validated against the skin.
    let mut bad = s.clone();
    bad.meshes[0].skin.as_mut().unwrap().joints[2] = [0, 2, 0, 0];
    assert!(
        matches!(bad.validate(), Err(SceneError::Element { ref reason, .. }) if reason.contains("vertex 2"))
    );
    let mut bad = s.clone();
    bad.meshes[0].skin.as_mut().unwrap().weights[1][0] = -1.0;
    assert!(bad.validate().is_err());
    let mut bad = s;
    bad.skins[0].inverse_bind.pop();
    assert!(bad.validate().is_err());
}

/// SimpleSkin.gltf (two joints; the second rotates about z): every vertex
/// lands where the joint transforms read back from the file put it.
#[test]
fn simple_skin_poses_match_its_joints() {
    let s = load_gltf(Path::new("tests/data/SimpleSkin.gltf")).unwrap();
    assert_eq!((s.skins.len(), s.animations.len()), (1, 1));
    let i = s
        .instances
        .iter()
        .position(|x| x.skin.is_some())
        .expect("a skinned instance");
    let ch = &s.animations[0].channels[0];
    let Keys::Rotation(q) = &ch.keys else {
        panic!("a rotation channel")
    };
    // The key with the largest bend, evaluated exactly at its time.
    let k = (0..q.len())
        .max_by(|&a, &b| q[a].z.abs().total_cmp(&q[b].z.abs()))
        .unwrap();
    let time = ch.times[k];
    let pose = s.pose(time);
    let (p, _) = s.deformed(i, &pose);
    let mesh = &s.meshes[s.instances[i].mesh];
    let w = mesh.skin.as_ref().unwrap();
    let skin = &s.skins[0];
    // Joint world transforms by hand: joint 0 = T(0,1,0), joint 1 =
    // joint 0 * R(q).
    let g0 = Affine3A::from_translation(Vec3::Y);
    // (The file's keys are unit to 3 decimals; the pose uses them
    // normalized, as must any reader.)
    let g1 = g0 * Affine3A::from_quat(q[k].normalize());
    let m = [g0 * skin.inverse_bind[0], g1 * skin.inverse_bind[1]];
    assert!(q[k].z.abs() > 0.5, "the chosen key bends");
    for v in 0..mesh.positions.len() {
        let want = (0..4)
            .map(|c| {
                m[w.joints[v][c] as usize].transform_point3(mesh.positions[v]) * w.weights[v][c]
            })
            .sum::<Vec3>()
            / w.weights[v].iter().sum::<f32>();
        let world = pose.instances[i].transform_point3(p[v]);
        assert!(close(world, want, 1e-5), "vertex {v}: {world} vs {want}");
    }
}

#[test]
fn camera_paths_pass_through_their_keys_and_see_their_target() {
    let key = |time: f32, eye: Vec3| CameraKey {
        time,
        eye,
        target: Vec3::ZERO,
    };
    let path = CameraPath {
        keys: vec![
            key(0.0, Vec3::new(0.0, 1.0, 5.0)),
            key(5.0, Vec3::new(5.0, 1.0, 0.0)),
            key(10.0, Vec3::new(0.0, 1.0, -5.0)),
        ],
        fov_y: 1.0,
    };
    assert!(path.validate().is_ok());
    assert_eq!(path.duration(), 10.0);
    for k in &path.keys {
        assert!(close(path.at(k.time).eye, k.eye, 1e-5));
    }
    assert_eq!(path.at(-1.0).eye, path.keys[0].eye);
    assert_eq!(path.at(99.0).eye, path.keys[2].eye);
    // Between keys it moves smoothly (the midpoint lies between).
    let mid = path.at(2.5).eye;
    assert!(mid.x > 0.0 && mid.x < 5.0 && mid.z > 0.0 && mid.z < 5.0);
    let cam = path.at(3.0);
    let f = cam.frustum(1.5, 0.1, 100.0);
    assert!(f.touches_sphere(cam.target, 0.0));
    let behind = cam.eye + (cam.eye - cam.target).normalize() * 3.0;
    assert!(!f.touches_sphere(behind, 1.0));
    assert!(
        f.touches_sphere(behind, 3.5),
        "a big enough sphere reaches in"
    );
    let mut bad = path.clone();
    bad.keys[1].time = 0.0;
    assert!(matches!(bad.validate(), Err(SceneError::Camera { .. })));
    let mut bad = path.clone();
    bad.fov_y = 4.0;
    assert!(bad.validate().is_err());
    let mut bad = path;
    bad.keys[0].eye = Vec3::ZERO;
    assert!(bad.validate().is_err());
}

#[test]
fn a_scene_loops_when_every_animation_starts_again_together() {
    let with = |durations: &[f32]| {
        let mut s = Scene::default();
        let node = s.add_node("n", None, Trs::default());
        for (k, &d) in durations.iter().enumerate() {
            s.animations.push(Animation::translation(
                &format!("a{k}"),
                node,
                &[(0.0, Vec3::ZERO), (d, Vec3::X)],
            ));
        }
        s
    };
    // Nothing moves: no loop.
    assert_eq!(Scene::default().loop_period(20.0), None);
    assert_eq!(with(&[0.0]).loop_period(20.0), None);
    assert_eq!(with(&[2.0]).loop_period(20.0), Some(2.0));
    // The longest duration times the least whole number the others divide.
    assert_eq!(with(&[2.0, 1.0, 0.5]).loop_period(20.0), Some(2.0));
    assert_eq!(with(&[2.0, 3.0]).loop_period(20.0), Some(6.0));
    assert_eq!(with(&[1.5, 2.0]).loop_period(20.0), Some(6.0));
    // To a part in 10^6 (glTF key times are floats), each at most 10^4
    // times.
    assert_eq!(with(&[2.0, 2.0 / 3.0]).loop_period(20.0), Some(2.0));
    assert_eq!(with(&[2.0, 1.000_000_5]).loop_period(20.0), Some(2.0));
    assert_eq!(with(&[2.0, 1.000_05]).loop_period(20.0), None);
    assert_eq!(with(&[2.0, 4e-4]).loop_period(20.0), Some(2.0));
    assert_eq!(with(&[2.0, 1e-4]).loop_period(20.0), None);
    // Not past the longest asked for, nor past 16 times the longest.
    assert_eq!(with(&[8.0, 18.0]).loop_period(20.0), None);
    assert_eq!(with(&[8.0, 18.0]).loop_period(100.0), Some(72.0));
    assert_eq!(with(&[1.0, 17.0 / 16.0]).loop_period(100.0), Some(17.0));
    assert_eq!(with(&[1.0, 18.0 / 17.0]).loop_period(100.0), None);
    assert_eq!(with(&[2.0, f32::NAN]).loop_period(20.0), Some(2.0));
}
