//! A scene's geometry as glTF 2.0 binary (`.glb`) for a client to draw:
//! one mesh per scene mesh (positions, normals, `u32` indices) and one
//! node per instance, at its world transform at time 0, whose `extras`
//! name the instance id of the stream (`psao_instance`) and whether its
//! points live in bind space (`bind_space`: the client looks it up by the
//! mesh's own positions and normals, spec/wire-format.md 6.1). A skinned
//! mesh also carries `JOINTS_0` and `WEIGHTS_0`, and its instance's node
//! `extras.psao_skin` its joint matrices (instance-local, as
//! [`Pose::joints`](crate::Pose::joints)) sampled over the scene's
//! animation loop ([`Scene::duration`]), so a client poses it at any scene
//! time with linear blend skinning and places it with the stream's
//! `Transform`. A morphing mesh carries its targets (`targets`, with its
//! rest `weights`), and its instance's node `extras.psao_morph` its weights
//! sampled the same way ([`Pose::weights`](crate::Pose::weights)).
//! Materials, alpha masks and the animations themselves are not written.

use glam::Affine3A;
use serde_json::json;

use crate::error::SceneError;
use crate::model::scene::Scene;

/// glTF's component types and buffer targets.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const UNSIGNED_SHORT: u32 = 5123;

/// Samples a second of the joint matrices' loop.
pub const SKIN_SAMPLES_PER_SECOND: f32 = 30.0;

/// The most samples of one skinned instance's loop (longer loops are
/// sampled more sparsely).
pub const MAX_SKIN_SAMPLES: usize = 3600;

/// The most bytes of sampled joint matrices in one export, over all
/// skinned instances: a scene past it is refused with an error.
pub const MAX_SKIN_BYTES: usize = 256 << 20;
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
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(
            json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target}),
        );
        views.len() - 1
    };
    // glTF allows no empty accessor: a mesh without triangles is left
    // out, and its instances get nodes without a mesh.
    let mut mesh_index: Vec<Option<usize>> = Vec::with_capacity(scene.meshes.len());
    for m in &scene.meshes {
        if m.positions.is_empty() || m.indices.is_empty() {
            mesh_index.push(None);
            continue;
        }
        mesh_index.push(Some(meshes.len()));
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
        let mut attributes = json!({"POSITION": a - 3, "NORMAL": a - 2});
        if let Some(w) = m
            .skin
            .as_ref()
            .filter(|w| w.joints.len() == m.positions.len() && w.weights.len() == m.positions.len())
        {
            let joints: Vec<u8> = w
                .joints
                .iter()
                .flatten()
                .flat_map(|j| j.to_le_bytes())
                .collect();
            let jv = view(&mut bin, &joints, ARRAY_BUFFER);
            accessors.push(json!({"bufferView": jv, "componentType": UNSIGNED_SHORT, "count": w.joints.len(), "type": "VEC4"}));
            let weights: Vec<u8> = w
                .weights
                .iter()
                .flatten()
                .flat_map(|x| x.to_le_bytes())
                .collect();
            let wv = view(&mut bin, &weights, ARRAY_BUFFER);
            accessors.push(json!({"bufferView": wv, "componentType": FLOAT, "count": w.weights.len(), "type": "VEC4"}));
            attributes["JOINTS_0"] = json!(accessors.len() - 2);
            attributes["WEIGHTS_0"] = json!(accessors.len() - 1);
        }
        let mut primitive = json!({"attributes": attributes, "indices": a - 1, "mode": 4});
        let mut mesh = json!({"primitives": [], "extras": {"double_sided": m.double_sided}});
        if let Some(t) = m
            .morph
            .as_ref()
            .filter(|t| t.check(m.positions.len()).is_ok() && !t.is_empty())
        {
            // The targets' offsets, applied as (weight - rest weight) times
            // the offset to the mesh as stored (MorphTargets::apply).
            let mut targets = Vec::new();
            for k in 0..t.len() {
                let mut target = json!({});
                for (name, offsets) in [("POSITION", &t.positions[k]), ("NORMAL", &t.normals[k])] {
                    if offsets.is_empty() {
                        continue;
                    }
                    let v = view(&mut bin, &floats(offsets), ARRAY_BUFFER);
                    accessors.push(json!({"bufferView": v, "componentType": FLOAT, "count": offsets.len(), "type": "VEC3"}));
                    target[name] = json!(accessors.len() - 1);
                }
                targets.push(target);
            }
            primitive["targets"] = json!(targets);
            mesh["weights"] = json!(t.rest_weights);
        }
        mesh["primitives"] = json!([primitive]);
        meshes.push(mesh);
    }
    let pose = scene.pose(0.0);
    let skins = SkinSamples::of(scene)?;
    let mut nodes = Vec::with_capacity(scene.instances.len());
    for (i, inst) in scene.instances.iter().enumerate() {
        let world = pose.instances.get(i).copied().unwrap_or(Affine3A::IDENTITY);
        let mut node = json!({"matrix": glam::Mat4::from(world).to_cols_array(),
            "extras": {"psao_instance": i, "bind_space": bind_space(i)}});
        let Some(mesh) = mesh_index[inst.mesh] else {
            nodes.push(node);
            continue;
        };
        node["mesh"] = json!(mesh);
        let m = &scene.meshes[inst.mesh];
        let skinned = m.skin.as_ref().is_some_and(|w| {
            w.joints.len() == m.positions.len() && w.weights.len() == m.positions.len()
        });
        if let Some((joints, floats)) = skins.matrices(i).filter(|_| skinned) {
            let bytes: Vec<u8> = floats.iter().flat_map(|x| x.to_le_bytes()).collect();
            let v = view(&mut bin, &bytes, ARRAY_BUFFER);
            accessors.push(json!({"bufferView": v, "componentType": FLOAT, "count": floats.len(), "type": "SCALAR"}));
            node["extras"]["psao_skin"] = json!({"joints": joints, "fps": skins.fps, "frames": skins.frames,
                "duration": skins.duration, "matrices": accessors.len() - 1});
        }
        if let Some((targets, weights)) = skins.weights(i).filter(|_| {
            m.morph
                .as_ref()
                .is_some_and(|t| t.check(m.positions.len()).is_ok())
        }) {
            let bytes: Vec<u8> = weights.iter().flat_map(|x| x.to_le_bytes()).collect();
            let v = view(&mut bin, &bytes, ARRAY_BUFFER);
            accessors.push(json!({"bufferView": v, "componentType": FLOAT, "count": weights.len(), "type": "SCALAR"}));
            node["extras"]["psao_morph"] = json!({"targets": targets, "fps": skins.fps, "frames": skins.frames,
                "duration": skins.duration, "weights": accessors.len() - 1});
        }
        nodes.push(node);
    }
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

/// Every skinned instance's joint matrices, and every morphing one's
/// weights, over the animation loop.
struct SkinSamples {
    fps: f32,
    frames: usize,
    duration: f32,
    /// Per instance: joints and `frames * joints * 12` floats (columns x,
    /// y, z, translation), or nothing.
    per_instance: Vec<Option<(usize, Vec<f32>)>>,
    /// Per instance: targets and `frames * targets` weights, or nothing.
    morphs: Vec<Option<(usize, Vec<f32>)>>,
}

impl SkinSamples {
    fn of(scene: &Scene) -> Result<SkinSamples, SceneError> {
        let duration = scene.duration().max(0.0);
        let fps = if duration > 0.0 {
            SKIN_SAMPLES_PER_SECOND.min((MAX_SKIN_SAMPLES - 1) as f32 / duration)
        } else {
            SKIN_SAMPLES_PER_SECOND
        };
        let frames = (duration * fps).ceil() as usize + 1;
        let mut per_instance: Vec<Option<(usize, Vec<f32>)>> = vec![None; scene.instances.len()];
        let skinned: Vec<usize> = (0..scene.instances.len())
            .filter(|&i| scene.instances[i].skin.is_some())
            .collect();
        let morphing: Vec<usize> = (0..scene.instances.len())
            .filter(|&i| scene.meshes[scene.instances[i].mesh].morph.is_some())
            .collect();
        let mut morphs: Vec<Option<(usize, Vec<f32>)>> = vec![None; scene.instances.len()];
        let bytes: usize = skinned
            .iter()
            .map(|&i| {
                let joints = scene.instances[i]
                    .skin
                    .and_then(|k| scene.skins.get(k))
                    .map_or(0, |k| k.joints.len());
                frames * joints * 48
            })
            .chain(morphing.iter().map(|&i| {
                let targets = scene.meshes[scene.instances[i].mesh]
                    .morph
                    .as_ref()
                    .map_or(0, |m| m.len());
                frames * targets * 4
            }))
            .sum();
        if bytes > MAX_SKIN_BYTES {
            return Err(SceneError::Element {
                element: "glTF export".into(),
                reason: format!(
                    "{bytes} bytes of sampled joint matrices ({} skinned instances, {frames} samples), above {MAX_SKIN_BYTES}",
                    skinned.len()
                ),
            });
        }
        if !skinned.is_empty() || !morphing.is_empty() {
            let mut pose = crate::Pose::default();
            for k in 0..frames {
                scene.pose_into((k as f32 / fps).min(duration), &mut pose);
                for &i in &morphing {
                    let targets = scene.meshes[scene.instances[i].mesh]
                        .morph
                        .as_ref()
                        .map_or(0, |m| m.len());
                    let (_, w) = morphs[i].get_or_insert_with(|| (targets, Vec::new()));
                    let now = &pose.weights[i];
                    // As MorphTargets::apply: a missing weight is the rest one.
                    w.extend((0..targets).map(|t| {
                        now.get(t).copied().unwrap_or_else(|| {
                            scene.meshes[scene.instances[i].mesh]
                                .morph
                                .as_ref()
                                .map_or(0.0, |m| m.rest_weights[t])
                        })
                    }));
                }
                for &i in &skinned {
                    let joints = &pose.joints[i];
                    let (_, floats) =
                        per_instance[i].get_or_insert_with(|| (joints.len(), Vec::new()));
                    for j in joints {
                        floats.extend_from_slice(&j.to_cols_array());
                    }
                }
            }
        }
        Ok(SkinSamples {
            fps,
            frames,
            duration,
            per_instance,
            morphs,
        })
    }

    fn weights(&self, i: usize) -> Option<(usize, &[f32])> {
        self.morphs[i]
            .as_ref()
            .filter(|(t, _)| *t > 0)
            .map(|(t, w)| (*t, w.as_slice()))
    }

    fn matrices(&self, i: usize) -> Option<(usize, &[f32])> {
        self.per_instance[i]
            .as_ref()
            .filter(|(j, _)| *j > 0)
            .map(|(j, f)| (*j, f.as_slice()))
    }
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
            assert_eq!(
                node["extras"].get("psao_skin").is_some(),
                i == walker,
                "instance {i}"
            );
        }
        // The walker's samples are its pose's joint matrices: sample k at
        // k / fps, and linear blend skinning with them puts a vertex where
        // the scene's own skinning does.
        let skin = &root["nodes"][walker]["extras"]["psao_skin"];
        let (joints, fps) = (
            skin["joints"].as_u64().unwrap() as usize,
            skin["fps"].as_f64().unwrap() as f32,
        );
        let acc = &root["accessors"][skin["matrices"].as_u64().unwrap() as usize];
        let view = &root["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
        let at = view["byteOffset"].as_u64().unwrap() as usize;
        let bin = glb.bin.as_ref().unwrap();
        let float =
            |k: usize| f32::from_le_bytes(bin[at + 4 * k..at + 4 * k + 4].try_into().unwrap());
        let k = 7;
        let pose = scene.pose(k as f32 / fps);
        let j = &pose.joints[walker];
        assert_eq!(j.len(), joints);
        for (n, m) in j.iter().enumerate() {
            let base = (k * joints + n) * 12;
            assert_eq!(float(base + 9), m.translation.x, "joint {n}");
            assert_eq!(float(base + 4), m.matrix3.y_axis.y, "joint {n}");
        }
    }
}
