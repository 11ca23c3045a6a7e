//! glTF import on real models, and clear errors on broken ones.

use std::path::PathBuf;

use glam::Vec3;
use psao_scene::*;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

#[test]
fn cornell_box_loads_as_a_closed_room() {
    let s = load_gltf(&data("CornellBox.glb")).unwrap();
    let tris = s.world_triangles().unwrap();
    assert_eq!(tris.len(), 36);
    assert!(tris.iter().flatten().all(|p| p.is_finite()));
    // Points spread over it and AO traced inside: the room occludes.
    let tracer = AoTracer::new(&tris);
    let (lo, hi) = tris
        .iter()
        .flatten()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), p| {
            (a.min(*p), b.max(*p))
        });
    let centre = (lo + hi) * 0.5;
    let r = tracer
        .trace(
            &[centre],
            &[Vec3::Y],
            &AoParams {
                radius: (hi - lo).max_element() * 2.0,
                rays: 64,
                ..AoParams::default()
            },
        )
        .unwrap();
    assert!(r.ao[0] < 1.0, "inside the room some rays hit: {:?}", r.ao);
}

#[test]
fn box_animated_composes_node_transforms() {
    let s = load_gltf(&data("BoxAnimated.glb")).unwrap();
    assert!(s.validate().is_ok());
    // Nodes 2 (under 0 -> 1) and 3 hold meshes 0 and 1.
    assert_eq!(s.instances.len(), 2);
    assert!(s.meshes.iter().map(|m| m.triangle_count()).sum::<usize>() > 100);
    // One animation drives the second box; the first stays.
    assert_eq!(s.animations.len(), 1);
    assert_eq!(s.dynamic_instances(), vec![false, true]);
    // Nodes 0 and 2 carry the quaternion (0, 0, 0, -1): composed along the
    // hierarchy the static box has the identity rotation.
    let pose = s.pose(0.0);
    let m = pose.instances[0].to_cols_array();
    let id = glam::Affine3A::IDENTITY.to_cols_array();
    assert!(m.iter().zip(id).all(|(a, b)| (a - b).abs() < 1e-6), "{m:?}");
    // The animated one moves over time.
    assert_ne!(s.pose(0.5).instances[1], s.pose(1.5).instances[1]);
}

#[test]
fn skinned_and_animated_models_load_and_move() {
    // (file, joints, animations, duration of the first)
    let models = [
        ("RiggedSimple.glb", 2, 1, 2.083),
        ("RiggedFigure.glb", 19, 1, 1.25),
        ("Fox.glb", 24, 3, 3.417),
    ];
    for (file, joints, anims, duration) in models {
        let s = load_gltf(&data(file)).unwrap();
        assert_eq!(s.skins.len(), 1, "{file}");
        assert_eq!(s.skins[0].joints.len(), joints, "{file}");
        assert_eq!(s.animations.len(), anims, "{file}");
        assert!(
            (s.animations[0].duration() - duration).abs() < 1e-3,
            "{file}"
        );
        let i = s.instances.iter().position(|x| x.skin.is_some()).unwrap();
        assert!(s.dynamic_instances()[i], "{file}");
        // The mesh deforms: some vertex moves between two times, and every
        // vertex stays finite.
        let (a, b) = (s.pose(0.0), s.pose(duration * 0.5));
        let (pa, _) = s.deformed(i, &a);
        let (pb, _) = s.deformed(i, &b);
        assert!(pa.iter().chain(pb.iter()).all(|p| p.is_finite()), "{file}");
        let moved = pa
            .iter()
            .zip(pb.iter())
            .map(|(x, y)| x.distance(*y))
            .fold(0.0, f32::max);
        assert!(moved > 1e-3, "{file}: nothing moved");
    }
    // Alternatives can be narrowed to one.
    let mut fox = load_gltf(&data("Fox.glb")).unwrap();
    fox.select_animation("Walk").unwrap();
    assert_eq!(fox.animations.len(), 1);
    assert!((fox.duration() - 0.708).abs() < 1e-3);
    let e = fox.select_animation("Dance").unwrap_err();
    assert!(e.to_string().contains("Walk"), "{e}");
    // A rigid rotation animation.
    let tri = load_gltf(&data("AnimatedTriangle.gltf")).unwrap();
    assert_eq!(tri.dynamic_instances(), vec![true]);
    let q = |t: f32| tri.pose(t).instances[0];
    assert_ne!(q(0.0), q(0.25));
}

#[test]
fn cesium_man_walks_in_place_with_its_skin() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/CesiumMan.glb");
    let s = load_gltf(&path).unwrap();
    assert_eq!(s.skins[0].joints.len(), 19);
    assert_eq!(s.animations.len(), 1);
    assert_eq!(s.meshes[0].triangle_count(), 4672);
    assert!((s.duration() - 2.0).abs() < 1e-3);
    let i = s.instances.iter().position(|x| x.skin.is_some()).unwrap();
    for t in [0.0, 0.5, 1.0, 1.5] {
        let pose = s.pose(t);
        let (p, n) = s.deformed(i, &pose);
        let world: Vec<Vec3> = p
            .iter()
            .map(|&v| pose.instances[i].transform_point3(v))
            .collect();
        let lo = world.iter().fold(Vec3::INFINITY, |a, b| a.min(*b));
        let hi = world.iter().fold(Vec3::NEG_INFINITY, |a, b| a.max(*b));
        // A person about 1.5 m tall standing on y = 0, whatever the pose.
        assert!(
            (lo.y).abs() < 0.05 && (hi.y - 1.47).abs() < 0.08,
            "t {t}: {lo} {hi}"
        );
        assert!(n.iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
    }
}

#[test]
fn skin_and_animation_errors_name_the_element() {
    // A minimal skinned triangle, then broken one way at a time.
    let doc = |skin: &str, anim: &str, joints: u32| {
        format!(
            r#"{{
        "asset": {{"version": "2.0"}},
        "buffers": [{{"uri": "data:application/octet-stream;base64,{b64}", "byteLength": 104}}],
        "bufferViews": [{{"buffer": 0, "byteLength": 36}}, {{"buffer": 0, "byteOffset": 36, "byteLength": 48}},
                        {{"buffer": 0, "byteOffset": 84, "byteLength": 8}}, {{"buffer": 0, "byteOffset": 92, "byteLength": 12}}],
        "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
                      {{"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC4"}},
                      {{"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0], "max": [1]}},
                      {{"bufferView": 3, "componentType": 5121, "count": {joints}, "type": "VEC4"}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "WEIGHTS_0": 1, "JOINTS_0": 3}}}}]}}],
        "nodes": [{{"mesh": 0, "skin": 0}}, {{"name": "bone"}}],
        "skins": [{skin}],
        "animations": [{anim}],
        "scenes": [{{"nodes": [0, 1]}}]
    }}"#,
            b64 = BUFFER_B64
        )
    };
    let good_skin = r#"{"joints": [1]}"#;
    let good_anim = r#"{"channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}],
                        "samplers": [{"input": 2, "output": 0}]}"#;
    let load = |json: String| load_gltf_slice(json.as_bytes(), "skin.gltf", None);
    // The translation keys: 3 values (accessor 0) for 2 times.
    let e = load(doc(good_skin, good_anim, 3)).unwrap_err();
    assert!(
        e.to_string()
            .contains("animation 0 channel 0: 3 values for 2 keys"),
        "{e}"
    );
    let fixed = good_anim.replace(r#""output": 0"#, r#""output": 0, "interpolation": "STEP""#);
    assert!(load(doc(good_skin, &fixed, 3)).is_err());
    // JOINTS_0 with 2 elements for 3 vertices.
    let e = load(doc(good_skin, good_anim, 2)).unwrap_err();
    assert!(
        e.to_string().contains("JOINTS") && e.to_string().contains("mesh 0 primitive 0"),
        "{e}"
    );
    // Inverse bind matrices that are not MAT4.
    let e = load(doc(
        r#"{"joints": [1], "inverseBindMatrices": 2}"#,
        good_anim,
        3,
    ))
    .unwrap_err();
    assert!(
        e.to_string().contains("skin 0") && e.to_string().contains("MAT4"),
        "{e}"
    );
    // Channels gltf-json leaves unchecked: a bad path, a node past the end.
    let bogus = good_anim.replace("translation", "bogus");
    let e = load(doc(good_skin, &bogus, 3)).unwrap_err();
    assert!(
        e.to_string().contains("animation 0 channel 0: target path"),
        "{e}"
    );
    let far = good_anim.replace(r#""node": 1"#, r#""node": 9"#);
    let e = load(doc(good_skin, &far, 3)).unwrap_err();
    assert!(e.to_string().contains("targets node 9 of 2"), "{e}");
    // Morph target weights.
    let morph = good_anim.replace("translation", "weights");
    let e = load(doc(good_skin, &morph, 3)).unwrap_err();
    assert!(
        e.to_string().contains("animation 0 channel 0") && e.to_string().contains("morph"),
        "{e}"
    );
}

/// 104 bytes: three positions (0,0,0) (1,0,0) (0,1,0), three weights
/// (1,0,0,0), times 0 and 1, then three zero joint sets (u8 VEC4).
const BUFFER_B64: &str = "AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAIA/AAAAAAAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAA=";

#[test]
fn data_uri_buffers_load() {
    // SimpleSkin.gltf keeps its buffers in base64 data URIs; the skinned
    // mesh is imported in its bind pose.
    let s = load_gltf(&data("SimpleSkin.gltf")).unwrap();
    assert_eq!(
        s.meshes.iter().map(|m| m.triangle_count()).sum::<usize>(),
        8
    );
}

#[test]
fn broken_files_name_the_file_and_element() {
    let missing = load_gltf(&data("nope.glb")).unwrap_err();
    assert!(
        matches!(&missing, SceneError::Gltf { element, .. } if element == "file"),
        "{missing}"
    );
    assert!(missing.to_string().contains("nope.glb"));

    let bytes = std::fs::read(data("CornellBox.glb")).unwrap();
    let cut = load_gltf_slice(&bytes[..bytes.len() / 2], "cut.glb", None).unwrap_err();
    assert!(cut.to_string().starts_with("cut.glb: "), "{cut}");

    let garbage = load_gltf_slice(b"not a model", "garbage.gltf", None).unwrap_err();
    assert!(
        matches!(&garbage, SceneError::Gltf { element, .. } if element == "document"),
        "{garbage}"
    );

    // A .gltf pointing at a buffer file that is not there.
    let json = br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"missing.bin","byteLength":12}]}"#;
    let dir = std::env::temp_dir();
    let e = load_gltf_slice(json, "ext.gltf", Some(&dir)).unwrap_err();
    assert!(
        matches!(&e, SceneError::Gltf { element, .. } if element == "buffer 0"),
        "{e}"
    );
    // ... or one declaring more than the importer accepts.
    let json =
        br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"big.bin","byteLength":4000000000}]}"#;
    let e = load_gltf_slice(json, "big.gltf", Some(&dir)).unwrap_err();
    assert!(e.to_string().contains("byte limit"), "{e}");
    // An external file longer than declared is read only up to the length.
    let folder = std::env::temp_dir().join(format!("psao-gltf-{}", std::process::id()));
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(folder.join("long.bin"), vec![0u8; 4096]).unwrap();
    let json = br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"long.bin","byteLength":12}]}"#;
    assert!(
        load_gltf_slice(json, "long.gltf", Some(&folder))
            .is_err_and(|e| e.to_string().contains("scene"))
    );
    std::fs::remove_dir_all(&folder).ok();
    // ... or one that tries to leave the model's folder.
    let json =
        br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"../etc/passwd","byteLength":12}]}"#;
    let e = load_gltf_slice(json, "escape.gltf", Some(&dir)).unwrap_err();
    assert!(e.to_string().contains("leaves the model's folder"), "{e}");
}

#[test]
fn accessors_outside_their_buffer_are_refused() {
    // 12 bytes of buffer (one vertex), but the POSITION accessor claims 3.
    let json = br#"{
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAA", "byteLength": 12}],
        "bufferViews": [{"buffer": 0, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [0, 0, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    }"#;
    let e = load_gltf_slice(json, "short.gltf", None).unwrap_err();
    assert!(
        matches!(&e, SceneError::Gltf { element, .. } if element == "mesh 0 primitive 0"),
        "{e}"
    );
    assert!(e.to_string().contains("POSITION accessor 0"), "{e}");
}

#[test]
fn glb_headers_and_binary_chunks_are_checked() {
    // A GLB header whose length is below its own 12 bytes (the gltf crate
    // would subtract and overflow).
    let e = load_gltf_slice(b"glTF\x02\0\0\0\x00\0\0\0", "short.glb", None).unwrap_err();
    assert!(e.to_string().contains("GLB header"), "{e}");
    let e = load_gltf_slice(b"glTF\x02\0", "tiny.glb", None).unwrap_err();
    assert!(e.to_string().contains("GLB header"), "{e}");
    // Only buffer 0 may be the binary chunk.
    let bytes = std::fs::read(data("CornellBox.glb")).unwrap();
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json = std::str::from_utf8(&bytes[20..20 + json_len]).unwrap();
    let start = json
        .find(r#""buffers":["#)
        .expect("the document lists buffers");
    let end = start + json[start..].find(']').unwrap();
    let mut doc = format!("{},{{\"byteLength\":4}}{}", &json[..end], &json[end..]);
    while doc.len() % 4 != 0 {
        doc.push(' ');
    }
    let bin = &bytes[20 + json_len..];
    let mut glb = Vec::new();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&((12 + 8 + doc.len() + bin.len()) as u32).to_le_bytes());
    glb.extend_from_slice(&(doc.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(doc.as_bytes());
    glb.extend_from_slice(bin);
    let e = load_gltf_slice(&glb, "two.glb", None).unwrap_err();
    assert!(e.to_string().contains("only buffer 0"), "{e}");
}

#[test]
fn morph_targets_take_their_default_weights() {
    // MorphPrimitivesTest: a flat 1 x 1 m plane at y = 0 whose two
    // primitives each carry a target lifting it by up to 0.2 m, at the
    // mesh's default weight 0.5.
    let s = load_gltf(&data("MorphPrimitivesTest.gltf")).unwrap();
    s.validate().unwrap();
    let ys: Vec<f32> = s
        .meshes
        .iter()
        .flat_map(|m| m.positions.iter().map(|p| p.y))
        .collect();
    let (lo, hi) = ys
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &y| (a.min(y), b.max(y)));
    assert!(lo.abs() < 1e-6, "the base stays at y = 0 ({lo})");
    assert!((hi - 0.1).abs() < 1e-3, "lifted by half of 0.2 m: {hi}");
    // Its targets move positions only, so the given normals stay (glTF
    // morphs a normal only by a target's NORMAL).
    assert!(
        s.meshes
            .iter()
            .flat_map(|m| &m.normals)
            .all(|n| n.is_normalized())
    );
    // No weights animate here: the targets are applied once, not kept.
    assert!(s.meshes.iter().all(|m| m.morph.is_none()));
}

#[test]
fn animated_morph_weights_deform_the_mesh_like_a_skin() {
    // AnimatedMorphCube: one mesh with 2 targets, its node's weights
    // driven by a linear animation over 4.2 s.
    let s = load_gltf(&data("AnimatedMorphCube.glb")).unwrap();
    s.validate().unwrap();
    assert_eq!(s.instances.len(), 1);
    let m = &s.meshes[s.instances[0].mesh];
    let morph = m.morph.as_ref().expect("the targets are kept");
    assert_eq!(morph.len(), 2);
    assert!(s.deforms(0) && s.dynamic_instances()[0]);
    assert!((s.duration() - 4.2).abs() < 1e-2, "{}", s.duration());
    // The weights follow the animation, and the vertices with them.
    let times = [0.0, 1.0, 2.0, 3.0];
    let poses: Vec<Pose> = times.iter().map(|&t| s.pose(t)).collect();
    assert!(poses.iter().all(|p| p.weights[0].len() == 2));
    assert!(
        poses.windows(2).any(|w| w[0].weights[0] != w[1].weights[0]),
        "{:?}",
        poses.iter().map(|p| &p.weights[0]).collect::<Vec<_>>()
    );
    let shapes: Vec<Vec<Vec3>> = poses
        .iter()
        .map(|p| s.deformed(0, p).0.into_owned())
        .collect();
    let moved = shapes
        .windows(2)
        .flat_map(|w| w[0].iter().zip(&w[1]).map(|(a, b)| a.distance(*b)))
        .fold(0.0f32, f32::max);
    assert!(moved > 1e-3, "nothing moved: {moved}");
    // A pose is the rest mesh plus each target's offset times its weight
    // change (glTF 3.7.2.1), normals renormalized.
    let p = &poses[2];
    let (pos, nrm) = s.deformed(0, p);
    for v in 0..m.positions.len() {
        let mut want = m.positions[v];
        for k in 0..2 {
            let dw = p.weights[0][k] - morph.rest_weights[k];
            if let Some(d) = morph.positions[k].get(v) {
                want += dw * *d;
            }
        }
        assert!(pos[v].distance(want) < 1e-5, "vertex {v}");
        assert!(nrm[v].is_normalized(), "normal {v}");
    }
    // Streamed, the mesh deforms tick after tick and the mirror keeps up.
    let staged = stage(s).unwrap();
    // Its mesh is 2 cm under a node that scales it by 100: 1024 points kept
    // per world square metre are 2 * 1024 * 100^2 spawned per mesh unit
    // (once refused as above 1e7).
    let dense = Pipeline::new(
        staged.clone(),
        PipelineConfig::with_density_and_rays(2048.0, 2),
    );
    assert!(dense.is_ok(), "{:?}", dense.err());
    let config = PipelineConfig {
        density: 64.0,
        ao: AoParams {
            rays: 8,
            ..AoParams::default()
        },
        ..PipelineConfig::default()
    };
    let mut pipe = Pipeline::new(staged, config).unwrap();
    let mut client = psao_codec::Decoder::new(psao_codec::Limits::default());
    client.receive(&pipe.keyframe().unwrap().bytes).unwrap();
    let mut deformed = 0;
    for _ in 0..20 {
        let (frame, report) = pipe.step(1.0 / 10.0).unwrap();
        deformed += report.deformed;
        if let Some(f) = frame {
            client.receive(&f.bytes).unwrap();
        }
    }
    assert!(
        deformed >= 10,
        "the cube deformed in {deformed} of 20 ticks"
    );
    let t = pipe.table(0).unwrap();
    let mirror = client.mirror().instance(0).unwrap();
    assert!(mirror.words() == t.words() && mirror.buckets() == t.buckets());
}

#[test]
fn the_first_perspective_camera_becomes_the_scene_camera_and_staging_keeps_it() {
    // Cameras.gltf: a perspective camera (yfov 0.7) and an orthographic
    // one, each on a node at (0.5, 0.5, 3) looking down -Z.
    let s = load_gltf(&data("Cameras.gltf")).unwrap();
    let path = s.camera.clone().expect("a camera path");
    assert_eq!(path.fov_y, 0.7);
    let cam = path.at(0.0);
    assert!(
        (cam.eye - Vec3::new(0.5, 0.5, 3.0)).length() < 1e-5,
        "{:?}",
        cam.eye
    );
    let look = (cam.target - cam.eye).normalize();
    assert!((look - Vec3::NEG_Z).length() < 1e-5, "{look:?}");
    // The bench stages the model on a floor and keeps the file's camera.
    let staged = stage(s).unwrap();
    assert_eq!(staged.camera, Some(path));
    // A file without cameras gets none (staging then orbits).
    assert!(
        load_gltf(&data("BoxAnimated.glb"))
            .unwrap()
            .camera
            .is_none()
    );
}

#[test]
fn morph_targets_are_capped_per_primitive() {
    // One triangle whose primitive lists `n` targets, each moving POSITION
    // by the triangle's own positions (accessor 0).
    let doc = |n: usize| {
        let targets = vec![r#"{"POSITION": 0}"#; n].join(",");
        format!(
            r#"{{
        "asset": {{"version": "2.0"}},
        "buffers": [{{"uri": "data:application/octet-stream;base64,{BUFFER_B64}", "byteLength": 104}}],
        "bufferViews": [{{"buffer": 0, "byteLength": 36}}],
        "accessors": [{{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "targets": [{targets}]}}]}}],
        "nodes": [{{"mesh": 0}}],
        "scenes": [{{"nodes": [0]}}]
    }}"#
        )
    };
    let load = |json: String| load_gltf_slice(json.as_bytes(), "morph.gltf", None);
    assert!(load(doc(MAX_MORPH_TARGETS)).is_ok());
    let e = load(doc(MAX_MORPH_TARGETS + 1)).unwrap_err().to_string();
    assert!(
        e.contains("257 morph targets, above 256") && e.contains("mesh 0 primitive 0"),
        "{e}"
    );
}
