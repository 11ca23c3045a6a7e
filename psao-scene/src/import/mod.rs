//! glTF 2.0 import (the `gltf` crate): the default scene's node hierarchy,
//! meshes, skins, animations and alpha-mask materials become a [`Scene`].
//!
//! Buffers come from the GLB binary chunk, `data:` URIs (base64) or files
//! next to the document. Nodes are kept (parents before children) with
//! their translation, rotation and scale; every mesh primitive is a
//! [`Mesh`](crate::Mesh), and every node that holds it an
//! [`Instance`](crate::Instance) hanging from the node (with the node's
//! skin, if any). Translation, rotation, scale and morph weight channels
//! become [`Animation`](crate::Animation)s. `MASK` materials become alpha masks from
//! the base colour factor and `COLOR_0`. Missing normals are computed from
//! the faces; missing indices mean sequential triangles. Morph targets are
//! applied with their default weights (the node's, else the mesh's): the
//! mesh is the weighted sum, its normals too (from the faces when it has
//! none). A node whose weights an animation drives keeps its targets as
//! [`MorphTargets`](crate::MorphTargets) and deforms as a skin does (its
//! normals follow the targets' NORMAL offsets; normals computed from the
//! faces stay those of the default weights). The first perspective camera in scene order becomes the scene's
//! camera path (following its node, looking down its -Z).
//!
//! Not supported, each refused with an error: more than four joints per
//! vertex, alpha masks read from textures, sparse accessors,
//! primitives other than triangle lists. Any problem is a
//! [`SceneError::Gltf`] naming the file and the element. Work is bounded:
//! every buffer is read once, at most [`MAX_BUFFER_BYTES`] in all, and the
//! accessors read from them at most [`MAX_ACCESSOR_BYTES`] in all; a
//! primitive has at most [`MAX_MORPH_TARGETS`] morph targets, and the
//! animated ones kept take at most [`MAX_MORPH_BYTES`].
//!
//! Here are the entry points and the limits; [`buffers`] reads the bytes
//! (buffers and accessors), [`nodes`] the node hierarchy, the instances on
//! it, skins and animations, [`mesh`] the primitives and [`material`] their
//! alpha masks.

mod buffers;
mod material;
mod mesh;
pub use mesh::{MAX_MORPH_BYTES, MAX_MORPH_TARGETS};
mod nodes;
pub(crate) mod obj;

use std::path::Path;

use crate::error::SceneError;
use crate::model::scene::Scene;
use buffers::load_buffers;
use nodes::{read_animation, read_camera, read_instances, read_nodes};

/// Most buffer bytes a glTF file may declare, all buffers together (1 GiB).
pub const MAX_BUFFER_BYTES: usize = 1 << 30;

/// Most bytes read out of accessors, all accessors together (1 GiB).
pub const MAX_ACCESSOR_BYTES: usize = 1 << 30;

/// Most mesh instances (node-primitive pairs) a file may produce.
pub const MAX_INSTANCES: usize = 65_536;

/// Most vertices over all skinned instances (each is skinned when the
/// scene is validated and posed).
pub const MAX_SKINNED_VERTICES: usize = 1 << 24;

/// Reads a `.gltf` or `.glb` file.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| gltf_error(&name, "file", e.to_string()))?;
    load_gltf_slice(&bytes, &name, path.parent())
}

/// Reads a scene file by its extension: `.gltf` or `.glb` ([`load_gltf`]),
/// `.obj` ([`obj::load_obj`]); any other is
/// [`SceneError::UnsupportedFormat`].
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "gltf" | "glb" => load_gltf(path),
        "obj" => obj::load_obj(path),
        _ => Err(SceneError::UnsupportedFormat {
            file: path.display().to_string(),
        }),
    }
}

/// Reads glTF from memory; `name` names it in errors, `base` is where
/// external buffers are looked up (none: external buffers are an error).
pub fn load_gltf_slice(bytes: &[u8], name: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    check_document(bytes, name)?;
    let gltf =
        gltf::Gltf::from_slice(bytes).map_err(|e| gltf_error(name, "document", e.to_string()))?;
    let buffers = load_buffers(&gltf, name, base)?;
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| gltf_error(name, "scenes", "the file has no scene".into()))?;
    let mut out = Scene::default();
    let (order, visited) = read_nodes(&scene, gltf.nodes().len(), name, &mut out)?;
    let node_of = |n: usize, what: &str| {
        order
            .get(n)
            .copied()
            .flatten()
            .ok_or_else(|| gltf_error(name, what, format!("node {n} is not in the scene")))
    };
    // Nodes whose morph weights an animation drives.
    let morphing: std::collections::HashSet<usize> = gltf
        .animations()
        .flat_map(|a| a.channels().collect::<Vec<_>>())
        .filter(|c| c.target().property() == gltf::animation::Property::MorphTargetWeights)
        .map(|c| c.target().node().index())
        .collect();
    read_instances(&visited, &morphing, &buffers, name, &node_of, &mut out)?;
    for anim in gltf.animations() {
        out.animations
            .push(read_animation(&anim, &buffers, name, &node_of)?);
    }
    let skinned: usize = out
        .instances
        .iter()
        .filter(|i| i.skin.is_some() || out.meshes[i.mesh].morph.is_some())
        .map(|i| out.meshes[i.mesh].positions.len())
        .fold(0, usize::saturating_add);
    if skinned > MAX_SKINNED_VERTICES {
        return Err(gltf_error(
            name,
            "skins",
            format!("{skinned} skinned vertices over all instances, above {MAX_SKINNED_VERTICES}"),
        ));
    }
    out.validate()
        .map_err(|e| gltf_error(name, "scene", e.to_string()))?;
    out.camera = read_camera(&visited, &node_of, &out)
        .map_err(|e| gltf_error(name, "camera", e.to_string()))?;
    Ok(out)
}

/// Checks on the unvalidated document what the `gltf` crate would panic on
/// (found by fuzzing) before it validates and reads it.
fn check_document(bytes: &[u8], name: &str) -> Result<(), SceneError> {
    // gltf-json 1.4's validation indexes the POSITION accessor without a
    // bounds check (a panic found by fuzzing): check attribute accessor
    // indices on the unvalidated document first, then validate.
    // gltf 1.4 subtracts 12 from a GLB header's length unchecked.
    if bytes.starts_with(b"glTF") {
        let length = bytes
            .get(8..12)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        if length.is_none_or(|l| l < 12) {
            return Err(gltf_error(
                name,
                "document",
                "GLB header is shorter than 12 bytes or declares a length below 12".into(),
            ));
        }
    }
    let raw = gltf::Gltf::from_slice_without_validation(bytes)
        .map_err(|e| gltf_error(name, "document", e.to_string()))?;
    let json = raw.as_json();
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(bad) = prim
                .attributes
                .values()
                .find(|a| a.value() >= json.accessors.len())
            {
                return Err(gltf_error(
                    name,
                    &format!("mesh {m} primitive {p}"),
                    format!(
                        "attribute accessor {} of {}",
                        bad.value(),
                        json.accessors.len()
                    ),
                ));
            }
        }
    }
    // gltf-json 1.4 does not validate animation channels (their target
    // node and path); the gltf crate unwraps both: check them here.
    for (a, anim) in json.animations.iter().enumerate() {
        for (c, ch) in anim.channels.iter().enumerate() {
            let element = || format!("animation {a} channel {c}");
            if ch.target.node.value() >= json.nodes.len() {
                return Err(gltf_error(
                    name,
                    &element(),
                    format!(
                        "targets node {} of {}",
                        ch.target.node.value(),
                        json.nodes.len()
                    ),
                ));
            }
            if !matches!(ch.target.path, gltf::json::validation::Checked::Valid(_)) {
                return Err(gltf_error(
                    name,
                    &element(),
                    "target path is not translation, rotation, scale or weights".into(),
                ));
            }
        }
    }
    Ok(())
}

/// A [`SceneError::Gltf`] naming `file` and `element`.
fn gltf_error(file: &str, element: &str, reason: String) -> SceneError {
    SceneError::Gltf {
        file: file.to_string(),
        element: element.to_string(),
        reason,
    }
}
