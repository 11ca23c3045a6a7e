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
    // Nodes 0 and 2 carry the quaternion (0, 0, 0, -1): composed along the
    // hierarchy they give the identity rotation.
    for i in &s.instances {
        let m = i.transform.to_cols_array();
        let id = glam::Affine3A::IDENTITY.to_cols_array();
        assert!(m.iter().zip(id).all(|(a, b)| (a - b).abs() < 1e-6), "{m:?}");
    }
}

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
