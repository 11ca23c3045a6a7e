//! Wavefront OBJ import (with its MTL materials) through tobj: one mesh
//! and one instance per OBJ object or group, in the file's units, Y up as
//! written. Faces are triangulated as fans; missing normals are made from
//! the faces; a material's dissolve (`d`, or `Tr` as `1 - Tr`) below 1
//! becomes a uniform alpha mask (cut out where it is below one half).
//! Texture-driven alpha (`map_d`) is not read. Untrusted input: the file
//! is read only up to [`MAX_OBJ_BYTES`]; at most [`MAX_MTL_FILES`]
//! material libraries, each a regular file inside the OBJ's folder of at
//! most [`MAX_MTL_BYTES`] (any other is left out: its faces stay solid);
//! at most [`MAX_INSTANCES`] objects; every index is checked.

use std::io::{BufReader, Read};
use std::path::Path;

use glam::{Affine3A, Vec3};

use super::MAX_INSTANCES;
use super::mesh::face_normals;
use crate::error::SceneError;
use crate::model::alpha::AlphaMask;
use crate::model::mesh::Mesh;
use crate::model::scene::Scene;

/// Largest OBJ file read (bytes).
pub const MAX_OBJ_BYTES: u64 = 1 << 30;

/// Largest material library read (bytes).
pub const MAX_MTL_BYTES: u64 = 16 << 20;

/// Most material libraries one OBJ file may name.
pub const MAX_MTL_FILES: usize = 16;

fn obj_error(file: &str, element: &str, reason: String) -> SceneError {
    SceneError::Obj {
        file: file.to_string(),
        element: element.to_string(),
        reason,
    }
}

/// Reads at most `cap` bytes of the regular file `path`, or says why not
/// (a device or a pipe is not read: it might never end).
pub(crate) fn read_capped(path: &Path, cap: u64) -> Result<Vec<u8>, String> {
    if !std::fs::metadata(path)
        .map_err(|e| e.to_string())?
        .is_file()
    {
        return Err("not a regular file".into());
    }
    let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let mut bytes = Vec::new();
    f.take(cap + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| e.to_string())?;
    if bytes.len() as u64 > cap {
        return Err(format!("larger than {cap} bytes"));
    }
    Ok(bytes)
}

/// Whether a material library name stays inside the OBJ file's folder (no
/// `..`, no absolute path).
fn stays_inside(name: &Path) -> bool {
    name.components().all(|c| {
        matches!(
            c,
            std::path::Component::Normal(_) | std::path::Component::CurDir
        )
    })
}

/// Reads an OBJ file and the material libraries beside it.
pub fn load_obj(path: &Path) -> Result<Scene, SceneError> {
    let name = path.display().to_string();
    let bytes = read_capped(path, MAX_OBJ_BYTES).map_err(|e| obj_error(&name, "file", e))?;
    load_obj_slice(&bytes, &name, path.parent())
}

/// Reads OBJ from memory; `name` names it in errors, `base` is where
/// material libraries are looked up (none: materials are left out).
pub fn load_obj_slice(bytes: &[u8], name: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    // One index per vertex, triangles, no points or lines: tobj's own
    // preset (it stays whole whatever tobj's optional features add).
    let options = tobj::GPU_LOAD_OPTIONS;
    let mut reader = BufReader::new(bytes);
    let libraries = std::sync::atomic::AtomicUsize::new(0);
    let (models, materials) = tobj::load_obj_buf(&mut reader, &options, |mtl| {
        let Some(dir) = base else {
            return Err(tobj::LoadError::OpenFileFailed);
        };
        let n = libraries.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if n >= MAX_MTL_FILES || !stays_inside(mtl) {
            return Err(tobj::LoadError::OpenFileFailed);
        }
        let data = read_capped(&dir.join(mtl), MAX_MTL_BYTES)
            .map_err(|_| tobj::LoadError::OpenFileFailed)?;
        tobj::load_mtl_buf(&mut BufReader::new(data.as_slice()))
    })
    .map_err(|e| obj_error(name, "document", e.to_string()))?;
    // A missing or broken material library leaves the faces solid.
    let materials = materials.unwrap_or_default();
    let mut scene = Scene::default();
    for (k, model) in models.iter().enumerate() {
        let element = || format!("object {k} ({})", model.name);
        if scene.instances.len() >= MAX_INSTANCES {
            return Err(obj_error(
                name,
                &element(),
                format!("more than {MAX_INSTANCES} objects with faces"),
            ));
        }
        let m = &model.mesh;
        if m.positions.len() % 3 != 0 || m.indices.len() % 3 != 0 {
            return Err(obj_error(
                name,
                &element(),
                "positions or faces not in threes".into(),
            ));
        }
        let positions: Vec<Vec3> = m
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        if let Some(&bad) = m.indices.iter().find(|&&i| i as usize >= positions.len()) {
            return Err(obj_error(
                name,
                &element(),
                format!("face index {bad} past its {} vertices", positions.len()),
            ));
        }
        if m.indices.is_empty() {
            continue;
        }
        let normals = if m.normals.len() == m.positions.len() {
            m.normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]).normalize_or_zero())
                .collect()
        } else {
            face_normals(&positions, &m.indices)
        };
        let alpha = m
            .material_id
            .and_then(|id| materials.get(id))
            .and_then(|mat| mat.dissolve)
            .filter(|&d| d.is_finite() && d < 1.0)
            .map(|d| AlphaMask {
                cutoff: 0.5,
                factor: d.max(0.0),
                vertex_alpha: Vec::new(),
                texture: None,
            });
        scene.add(
            Mesh {
                positions,
                normals,
                indices: m.indices.clone(),
                double_sided: false,
                skin: None,
                morph: None,
                alpha,
            },
            Affine3A::IDENTITY,
        );
    }
    if scene.instances.is_empty() {
        return Err(obj_error(name, "document", "no faces".into()));
    }
    scene
        .validate()
        .map_err(|e| obj_error(name, "document", e.to_string()))?;
    Ok(scene)
}
