//! glTF 2.0 import (the `gltf` crate): meshes and the node hierarchy of the
//! default scene become [`Mesh`]es and [`Instance`]s.
//!
//! Buffers come from the GLB binary chunk, `data:` URIs (base64) or files
//! next to the document; no texture is decoded. Every mesh primitive is a
//! mesh; every node that holds it is an instance with the node's composed
//! transform. Missing normals are computed from the faces; missing indices
//! mean sequential triangles. Skinned meshes are imported in their bind
//! pose (skinning comes with the animation slice). Any problem is a
//! [`SceneError::Gltf`] naming the file and the element.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use base64::Engine;
use glam::{Affine3A, Mat4, Vec3};
use gltf::mesh::Mode;

use crate::error::SceneError;
use crate::scene::{Instance, Mesh, Scene};

/// Largest buffer a glTF file may declare (1 GiB).
pub const MAX_BUFFER_BYTES: usize = 1 << 30;

/// Reads a `.gltf` or `.glb` file.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| gltf_error(&name, "file", e.to_string()))?;
    load_gltf_slice(&bytes, &name, path.parent())
}

/// Reads glTF from memory; `name` names it in errors, `base` is where
/// external buffers are looked up (none: external buffers are an error).
pub fn load_gltf_slice(bytes: &[u8], name: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    // gltf-json 1.4's validation indexes the POSITION accessor without a
    // bounds check (a panic found by fuzzing): check attribute accessor
    // indices on the unvalidated document first, then validate.
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
    let gltf =
        gltf::Gltf::from_slice(bytes).map_err(|e| gltf_error(name, "document", e.to_string()))?;
    let buffers = load_buffers(&gltf, name, base)?;
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| gltf_error(name, "scenes", "the file has no scene".into()))?;
    let mut out = Scene::default();
    let mut meshes: HashMap<(usize, usize), usize> = HashMap::new();
    let mut stack: Vec<(gltf::Node<'_>, Mat4, u32)> =
        scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 256 {
            return Err(gltf_error(
                name,
                &format!("node {}", node.index()),
                "hierarchy deeper than 256".into(),
            ));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            // A skinned mesh ignores its node transform (glTF 2.0, 3.7.3);
            // in the bind pose its vertices are where they are stored.
            let at = if node.skin().is_some() {
                Mat4::IDENTITY
            } else {
                world
            };
            let transform = Affine3A::from_mat4(at);
            if !transform.is_finite() {
                return Err(gltf_error(
                    name,
                    &format!("node {}", node.index()),
                    "transform is not finite".into(),
                ));
            }
            for prim in mesh.primitives() {
                let key = (mesh.index(), prim.index());
                let id = match meshes.get(&key) {
                    Some(&id) => id,
                    None => {
                        let element = format!("mesh {} primitive {}", mesh.index(), prim.index());
                        let m = primitive_mesh(&prim, &buffers, name, &element)?;
                        out.meshes.push(m);
                        meshes.insert(key, out.meshes.len() - 1);
                        out.meshes.len() - 1
                    }
                };
                out.instances.push(Instance {
                    mesh: id,
                    transform,
                });
            }
        }
        stack.extend(node.children().map(|c| (c, world, depth + 1)));
    }
    out.validate()
        .map_err(|e| gltf_error(name, "scene", e.to_string()))?;
    Ok(out)
}

fn gltf_error(file: &str, element: &str, reason: String) -> SceneError {
    SceneError::Gltf {
        file: file.to_string(),
        element: element.to_string(),
        reason,
    }
}

fn load_buffers(
    gltf: &gltf::Gltf,
    name: &str,
    base: Option<&Path>,
) -> Result<Vec<Vec<u8>>, SceneError> {
    let mut out = Vec::new();
    for buffer in gltf.buffers() {
        let element = format!("buffer {}", buffer.index());
        if buffer.length() > MAX_BUFFER_BYTES {
            return Err(gltf_error(
                name,
                &element,
                format!(
                    "declares {} bytes, above the {} byte limit",
                    buffer.length(),
                    MAX_BUFFER_BYTES
                ),
            ));
        }
        let data = match buffer.source() {
            gltf::buffer::Source::Bin => gltf.blob.clone().ok_or_else(|| {
                gltf_error(
                    name,
                    &element,
                    "refers to a missing GLB binary chunk".into(),
                )
            })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                let (_, payload) = uri
                    .split_once(";base64,")
                    .ok_or_else(|| gltf_error(name, &element, "data URI is not base64".into()))?;
                base64::engine::general_purpose::STANDARD
                    .decode(payload)
                    .map_err(|e| gltf_error(name, &element, format!("bad base64: {e}")))?
            }
            gltf::buffer::Source::Uri(uri) => {
                let dir = base.ok_or_else(|| {
                    gltf_error(
                        name,
                        &element,
                        format!("external buffer `{uri}` without a base folder"),
                    )
                })?;
                if uri.contains("..") || Path::new(uri).is_absolute() {
                    return Err(gltf_error(
                        name,
                        &element,
                        format!("buffer path `{uri}` leaves the model's folder"),
                    ));
                }
                // Read no more than the buffer declares, whatever the file holds.
                let mut data = Vec::new();
                std::fs::File::open(dir.join(uri))
                    .and_then(|f| f.take(buffer.length() as u64).read_to_end(&mut data))
                    .map_err(|e| gltf_error(name, &element, format!("`{uri}`: {e}")))?;
                data
            }
        };
        if data.len() < buffer.length() {
            return Err(gltf_error(
                name,
                &element,
                format!("holds {} bytes, declares {}", data.len(), buffer.length()),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

fn primitive_mesh(
    prim: &gltf::Primitive<'_>,
    buffers: &[Vec<u8>],
    name: &str,
    element: &str,
) -> Result<Mesh, SceneError> {
    if prim.mode() != Mode::Triangles {
        return Err(gltf_error(
            name,
            element,
            format!("mode {:?} is not supported (triangles only)", prim.mode()),
        ));
    }
    use gltf::accessor::{DataType, Dimensions};
    use gltf::mesh::Semantic;
    let read = |acc: gltf::Accessor<'_>, what: &str| {
        read_accessor(&acc, buffers).map_err(|r| {
            gltf_error(
                name,
                element,
                format!("{what} accessor {}: {r}", acc.index()),
            )
        })
    };
    let positions: Vec<Vec3> = match prim.get(&Semantic::Positions) {
        Some(a) if a.data_type() == DataType::F32 && a.dimensions() == Dimensions::Vec3 => {
            read(a, "POSITION")?.vec3()
        }
        Some(a) => {
            return Err(gltf_error(
                name,
                element,
                format!("POSITION accessor {} is not f32 VEC3", a.index()),
            ));
        }
        None => {
            return Err(gltf_error(
                name,
                element,
                "has no POSITION attribute".into(),
            ));
        }
    };
    let indices: Vec<u32> = match prim.indices() {
        Some(a) if a.dimensions() == Dimensions::Scalar => read(a, "index")?
            .u32s()
            .map_err(|r| gltf_error(name, element, r))?,
        Some(a) => {
            return Err(gltf_error(
                name,
                element,
                format!("index accessor {} is not SCALAR", a.index()),
            ));
        }
        None => (0..positions.len() as u32).collect(),
    };
    if indices.len() % 3 != 0 {
        return Err(gltf_error(
            name,
            element,
            format!("{} indices is not a multiple of 3", indices.len()),
        ));
    }
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(gltf_error(
            name,
            element,
            format!("index {bad} is past {} vertices", positions.len()),
        ));
    }
    let normals: Vec<Vec3> = match prim.get(&Semantic::Normals) {
        Some(a) if a.data_type() == DataType::F32 && a.dimensions() == Dimensions::Vec3 => {
            read(a, "NORMAL")?
                .vec3()
                .into_iter()
                .map(|n| n.normalize_or(Vec3::Z))
                .collect()
        }
        Some(a) => {
            return Err(gltf_error(
                name,
                element,
                format!("NORMAL accessor {} is not f32 VEC3", a.index()),
            ));
        }
        None => face_normals(&positions, &indices),
    };
    if normals.len() != positions.len() {
        return Err(gltf_error(
            name,
            element,
            "NORMAL and POSITION counts differ".into(),
        ));
    }
    Ok(Mesh {
        positions,
        normals,
        indices,
        double_sided: prim.material().double_sided(),
    })
}

/// Vertex normals as the area-weighted sum of the adjacent face normals.
fn face_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; positions.len()];
    for t in indices.chunks_exact(3) {
        let [a, b, c] = [t[0], t[1], t[2]].map(|i| positions[i as usize]);
        let f = (b - a).cross(c - a);
        for &i in t {
            n[i as usize] += f;
        }
    }
    n.into_iter().map(|v| v.normalize_or(Vec3::Z)).collect()
}

/// The raw elements of an accessor, each `size` bytes.
struct Elements {
    bytes: Vec<u8>,
    size: usize,
    kind: gltf::accessor::DataType,
}

impl Elements {
    fn vec3(&self) -> Vec<Vec3> {
        self.bytes
            .chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                Vec3::new(f(0), f(4), f(8))
            })
            .collect()
    }

    fn u32s(&self) -> Result<Vec<u32>, String> {
        use gltf::accessor::DataType;
        let c = self.bytes.chunks_exact(self.size);
        Ok(match self.kind {
            DataType::U8 => c.map(|b| b[0] as u32).collect(),
            DataType::U16 => c.map(|b| u16::from_le_bytes([b[0], b[1]]) as u32).collect(),
            DataType::U32 => c
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            other => {
                return Err(format!(
                    "index component type {other:?} is not an unsigned integer"
                ));
            }
        })
    }
}

/// Copies an accessor's elements out of its buffer view with every offset,
/// stride and length checked (the gltf crate's reader asserts instead).
fn read_accessor(acc: &gltf::Accessor<'_>, buffers: &[Vec<u8>]) -> Result<Elements, String> {
    if acc.sparse().is_some() {
        return Err("sparse accessors are not supported".into());
    }
    let view = acc.view().ok_or("has no buffer view")?;
    let size = acc.size();
    let stride = view.stride().unwrap_or(size);
    if size == 0 || stride < size {
        return Err(format!(
            "stride {stride} is shorter than the element ({size} bytes)"
        ));
    }
    let data = buffers
        .get(view.buffer().index())
        .ok_or("refers to a missing buffer")?;
    let view_end = view
        .offset()
        .checked_add(view.length())
        .filter(|&e| e <= data.len())
        .ok_or("buffer view runs past its buffer")?;
    let start = view
        .offset()
        .checked_add(acc.offset())
        .ok_or("offset overflows")?;
    let count = acc.count();
    if count > 0 {
        let last = (count - 1)
            .checked_mul(stride)
            .and_then(|x| x.checked_add(start))
            .and_then(|x| x.checked_add(size))
            .ok_or("size overflows")?;
        if last > view_end {
            return Err(format!("{count} elements run past the buffer view"));
        }
    }
    let mut bytes = Vec::with_capacity(count * size);
    for k in 0..count {
        let at = start + k * stride;
        bytes.extend_from_slice(&data[at..at + size]);
    }
    Ok(Elements {
        bytes,
        size,
        kind: acc.data_type(),
    })
}
