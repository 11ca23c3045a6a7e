//! A scene's geometry as glTF 2.0 binary (`.glb`) for a client to draw:
//! one mesh per scene mesh (positions, normals, `u32` indices) and one
//! node per instance, at its world transform at time 0, whose `extras`
//! name the instance id of the stream (`psao_instance`) and whether its
//! points live in bind space (`bind_space`: the client looks it up by the
//! mesh's own positions and normals, spec/wire-format.md 6.1). Materials,
//! alpha masks, skins and animations are not written: the stream's
//! `Transform` messages move rigid instances; a deforming instance is
//! drawn as stored (its bind pose).

use glam::Affine3A;
use serde_json::json;

use crate::error::SceneError;
use crate::model::scene::Scene;

/// glTF's component types and buffer targets.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The `.glb` bytes of `scene`'s geometry; `bind_space(i)` says whether
/// instance `i` is streamed in bind space (the pipeline's choice:
/// the point format of each instance's table, `Pipeline::table(i)`).
pub fn to_glb(scene: &Scene, bind_space: impl Fn(usize) -> bool) -> Result<Vec<u8>, SceneError> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut meshes) = (Vec::new(), Vec::new(), Vec::new());
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: u32| {
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push(
            json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target}),
        );
        views.len() - 1
    };
    for m in &scene.meshes {
        let floats = |v: &[glam::Vec3]| -> Vec<u8> {
            v.iter()
                .flat_map(|p| p.to_array())
                .flat_map(f32::to_le_bytes)
                .collect()
        };
        let (lo, hi) = m.bounds().unwrap_or_default();
        let pos = view(&mut bin, &floats(&m.positions), ARRAY_BUFFER);
        accessors.push(
            json!({"bufferView": pos, "componentType": FLOAT, "count": m.positions.len(),
            "type": "VEC3", "min": lo.to_array(), "max": hi.to_array()}),
        );
        let nrm = view(&mut bin, &floats(&m.normals), ARRAY_BUFFER);
        accessors.push(json!({"bufferView": nrm, "componentType": FLOAT, "count": m.normals.len(), "type": "VEC3"}));
        let idx: Vec<u8> = m.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let ix = view(&mut bin, &idx, ELEMENT_ARRAY_BUFFER);
        accessors.push(json!({"bufferView": ix, "componentType": UNSIGNED_INT, "count": m.indices.len(), "type": "SCALAR"}));
        let a = accessors.len();
        meshes.push(json!({"primitives": [{"attributes": {"POSITION": a - 3, "NORMAL": a - 2}, "indices": a - 1, "mode": 4}],
            "extras": {"double_sided": m.double_sided}}));
    }
    let pose = scene.pose(0.0);
    let nodes: Vec<_> = scene
        .instances
        .iter()
        .enumerate()
        .map(|(i, inst)| {
            let world = pose.instances.get(i).copied().unwrap_or(Affine3A::IDENTITY);
            json!({"mesh": inst.mesh, "matrix": glam::Mat4::from(world).to_cols_array(),
                "extras": {"psao_instance": i, "bind_space": bind_space(i)}})
        })
        .collect();
    let root = json!({
        "asset": {"version": "2.0", "generator": "psao-scene"},
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    let mut text = serde_json::to_vec(&root).map_err(|e| SceneError::Element {
        element: "glTF JSON".into(),
        reason: e.to_string(),
    })?;
    while text.len() % 4 != 0 {
        text.push(b' ');
    }
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: text.into(),
        bin: Some(bin.into()),
    };
    glb.to_vec().map_err(|e| SceneError::Element {
        element: "glTF binary".into(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::import::load_gltf_slice;
    use crate::scenes::default_scene::default_scene;

    /// The written file reads back (with the crate's own glTF import):
    /// every instance's mesh, triangle for triangle, at its transform.
    #[test]
    fn the_default_scene_reads_back() {
        let scene = default_scene();
        let bytes = to_glb(&scene, |i| scene.deforms(i)).unwrap();
        let back = load_gltf_slice(&bytes, "export.glb", None).unwrap();
        assert_eq!(back.instances.len(), scene.instances.len());
        let pose = scene.pose(0.0);
        let back_pose = back.pose(0.0);
        for i in 0..scene.instances.len() {
            let (a, b) = (
                &scene.meshes[scene.instances[i].mesh],
                &back.meshes[back.instances[i].mesh],
            );
            assert_eq!(a.indices, b.indices, "instance {i}");
            assert_eq!(a.positions, b.positions, "instance {i}");
            assert!(
                pose.instances[i].abs_diff_eq(back_pose.instances[i], 1e-5),
                "instance {i}"
            );
        }
        let glb = gltf::binary::Glb::from_slice(&bytes).unwrap();
        let root: serde_json::Value = serde_json::from_slice(&glb.json).unwrap();
        let walker = crate::scenes::default_scene::WALKER;
        for (i, node) in root["nodes"].as_array().unwrap().iter().enumerate() {
            assert_eq!(node["extras"]["psao_instance"], i);
            assert_eq!(node["extras"]["bind_space"], i == walker, "instance {i}");
        }
    }
}
