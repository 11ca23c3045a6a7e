//! glTF 2.0 import (the `gltf` crate): the default scene's node hierarchy,
//! meshes, skins, animations and alpha-mask materials become a [`Scene`].
//!
//! Buffers come from the GLB binary chunk, `data:` URIs (base64) or files
//! next to the document. Nodes are kept (parents before children) with
//! their translation, rotation and scale; every mesh primitive is a
//! [`Mesh`], and every node that holds it an [`Instance`] hanging from the
//! node (with the node's skin, if any). Translation, rotation and scale
//! channels become [`Animation`]s. `MASK` materials become alpha masks from
//! the base colour factor and `COLOR_0`. Missing normals are computed from
//! the faces; missing indices mean sequential triangles.
//!
//! Not supported, each refused with an error: morph targets, more than four
//! joints per vertex, alpha masks read from textures, sparse accessors,
//! primitives other than triangle lists. Any problem is a
//! [`SceneError::Gltf`] naming the file and the element. Work is bounded:
//! every buffer is read once, at most [`MAX_BUFFER_BYTES`] in all, and the
//! accessors read from them at most [`MAX_ACCESSOR_BYTES`] in all.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use base64::Engine;
use glam::{Affine3A, Mat4, Quat, Vec3};
use gltf::mesh::Mode;

use crate::alpha::AlphaMask;
use crate::animation::{Animation, Channel, Interpolation, Keys};
use crate::error::SceneError;
use crate::node::Trs;
use crate::scene::{Instance, Mesh, Scene};
use crate::skin::{Skin, SkinWeights};

/// Most buffer bytes a glTF file may declare, all buffers together (1 GiB).
pub const MAX_BUFFER_BYTES: usize = 1 << 30;

/// Most bytes read out of accessors, all accessors together (1 GiB).
pub const MAX_ACCESSOR_BYTES: usize = 1 << 30;

/// Most mesh instances (node-primitive pairs) a file may produce.
pub const MAX_INSTANCES: usize = 65_536;

/// Most vertices over all skinned instances (each is skinned when the
/// scene is validated and posed).
pub const MAX_SKINNED_VERTICES: usize = 1 << 24;

/// The file's buffers, and how many accessor bytes have been read from
/// them so far.
struct Buffers {
    data: Vec<Vec<u8>>,
    read: std::cell::Cell<usize>,
}

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
    let gltf =
        gltf::Gltf::from_slice(bytes).map_err(|e| gltf_error(name, "document", e.to_string()))?;
    let buffers = load_buffers(&gltf, name, base)?;
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| gltf_error(name, "scenes", "the file has no scene".into()))?;
    let mut out = Scene::default();
    // Nodes in depth-first order from the scene's roots, so parents come
    // before children; `order[gltf index]` is the node's index here.
    let mut order: Vec<Option<usize>> = vec![None; gltf.nodes().len()];
    let mut stack: Vec<(gltf::Node<'_>, Option<usize>, u32)> =
        scene.nodes().map(|n| (n, None, 0)).collect();
    stack.reverse();
    let mut visited = Vec::new();
    while let Some((node, parent, depth)) = stack.pop() {
        let element = format!("node {}", node.index());
        if depth > 256 {
            return Err(gltf_error(
                name,
                &element,
                "hierarchy deeper than 256".into(),
            ));
        }
        let slot = order
            .get_mut(node.index())
            .ok_or_else(|| gltf_error(name, &element, "index out of range".into()))?;
        if slot.is_some() {
            return Err(gltf_error(
                name,
                &element,
                "is reached twice (more than one parent, or a cycle)".into(),
            ));
        }
        let (t, r, sc) = match node.transform() {
            gltf::scene::Transform::Matrix { matrix } => {
                let (sc, r, t) = Mat4::from_cols_array_2d(&matrix).to_scale_rotation_translation();
                (t, r, sc)
            }
            gltf::scene::Transform::Decomposed {
                translation,
                rotation,
                scale,
            } => (
                Vec3::from(translation),
                Quat::from_array(rotation),
                Vec3::from(scale),
            ),
        };
        let trs = Trs {
            translation: t,
            rotation: r,
            scale: sc,
        };
        if !trs.is_finite() {
            return Err(gltf_error(name, &element, "transform is not finite".into()));
        }
        let index = out.add_node(node.name().unwrap_or(""), parent, trs);
        *slot = Some(index);
        visited.push(node.clone());
        let children: Vec<_> = node.children().collect();
        stack.extend(
            children
                .into_iter()
                .rev()
                .map(|c| (c, Some(index), depth + 1)),
        );
    }
    let node_of = |n: usize, what: &str| {
        order
            .get(n)
            .copied()
            .flatten()
            .ok_or_else(|| gltf_error(name, what, format!("node {n} is not in the scene")))
    };
    let mut skins: HashMap<usize, usize> = HashMap::new();
    let mut meshes: HashMap<(usize, usize), usize> = HashMap::new();
    for node in &visited {
        let here = node_of(node.index(), "scene")?;
        let Some(mesh) = node.mesh() else { continue };
        let skin = match node.skin() {
            Some(sk) => Some(match skins.get(&sk.index()) {
                Some(&i) => i,
                None => {
                    let skin = read_skin(&sk, &buffers, name, &node_of)?;
                    out.skins.push(skin);
                    skins.insert(sk.index(), out.skins.len() - 1);
                    out.skins.len() - 1
                }
            }),
            None => None,
        };
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
            if out.instances.len() >= MAX_INSTANCES {
                return Err(gltf_error(
                    name,
                    &format!("node {}", node.index()),
                    format!("more than {MAX_INSTANCES} mesh instances"),
                ));
            }
            out.instances.push(Instance {
                mesh: id,
                transform: Affine3A::IDENTITY,
                node: Some(here),
                // A skin only deforms a primitive that carries joints.
                skin: skin.filter(|_| out.meshes[id].skin.is_some()),
            });
        }
    }
    for anim in gltf.animations() {
        out.animations
            .push(read_animation(&anim, &buffers, name, &node_of)?);
    }
    let skinned: usize = out
        .instances
        .iter()
        .filter(|i| i.skin.is_some())
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
    Ok(out)
}

/// A skin: joints mapped to the scene's nodes, inverse bind matrices read
/// (identity when absent).
fn read_skin(
    skin: &gltf::Skin<'_>,
    buffers: &Buffers,
    name: &str,
    node_of: &dyn Fn(usize, &str) -> Result<usize, SceneError>,
) -> Result<Skin, SceneError> {
    let element = format!("skin {}", skin.index());
    let joints = skin
        .joints()
        .map(|j| node_of(j.index(), &element))
        .collect::<Result<Vec<_>, _>>()?;
    let inverse_bind = match skin.inverse_bind_matrices() {
        Some(acc) => {
            let what = format!("inverse bind matrix accessor {}", acc.index());
            let e = read_accessor(&acc, buffers)
                .map_err(|r| gltf_error(name, &element, format!("{what}: {r}")))?;
            if acc.dimensions() != gltf::accessor::Dimensions::Mat4
                || acc.data_type() != gltf::accessor::DataType::F32
            {
                return Err(gltf_error(
                    name,
                    &element,
                    format!("{what} is not f32 MAT4"),
                ));
            }
            let f = e.floats();
            let mut out = Vec::with_capacity(f.len() / 16);
            for (k, m) in f.chunks_exact(16).enumerate() {
                let m = Mat4::from_cols_slice(m);
                let row = m.row(3);
                if (row - glam::Vec4::W).abs().max_element() > 1e-4 || !m.is_finite() {
                    return Err(gltf_error(
                        name,
                        &element,
                        format!("inverse bind matrix {k} is not a finite affine transform"),
                    ));
                }
                out.push(Affine3A::from_mat4(m));
            }
            out
        }
        None => vec![Affine3A::IDENTITY; joints.len()],
    };
    if inverse_bind.len() != joints.len() {
        return Err(gltf_error(
            name,
            &element,
            format!(
                "{} inverse bind matrices for {} joints",
                inverse_bind.len(),
                joints.len()
            ),
        ));
    }
    Ok(Skin {
        name: skin.name().unwrap_or("").to_string(),
        joints,
        inverse_bind,
    })
}

/// An animation's translation, rotation and scale channels.
fn read_animation(
    anim: &gltf::Animation<'_>,
    buffers: &Buffers,
    name: &str,
    node_of: &dyn Fn(usize, &str) -> Result<usize, SceneError>,
) -> Result<Animation, SceneError> {
    use gltf::animation::{Interpolation as I, Property};
    let mut out = Animation {
        name: anim.name().unwrap_or("").to_string(),
        channels: Vec::new(),
    };
    for ch in anim.channels() {
        let element = format!("animation {} channel {}", anim.index(), ch.index());
        let target = ch.target();
        let node = node_of(target.node().index(), &element)?;
        let sampler = ch.sampler();
        let (input, output) = (sampler.input(), sampler.output());
        let read = |acc: &gltf::Accessor<'_>, what: &str| {
            read_accessor(acc, buffers).map_err(|r| {
                gltf_error(
                    name,
                    &element,
                    format!("{what} accessor {}: {r}", acc.index()),
                )
            })
        };
        if input.data_type() != gltf::accessor::DataType::F32
            || input.dimensions() != gltf::accessor::Dimensions::Scalar
        {
            return Err(gltf_error(
                name,
                &element,
                "key times are not f32 SCALAR".into(),
            ));
        }
        let times = read(&input, "input")?.floats();
        let values = read(&output, "output")?;
        let dims = output.dimensions();
        let want = match target.property() {
            Property::Rotation => gltf::accessor::Dimensions::Vec4,
            Property::MorphTargetWeights => {
                return Err(gltf_error(
                    name,
                    &element,
                    "morph target weights are not supported".into(),
                ));
            }
            _ => gltf::accessor::Dimensions::Vec3,
        };
        if dims != want {
            return Err(gltf_error(
                name,
                &element,
                format!("output is {dims:?}, expected {want:?}"),
            ));
        }
        let f = values.floats();
        let keys = match target.property() {
            Property::Translation => {
                Keys::Translation(f.chunks_exact(3).map(Vec3::from_slice).collect())
            }
            Property::Scale => Keys::Scale(f.chunks_exact(3).map(Vec3::from_slice).collect()),
            _ => Keys::Rotation(f.chunks_exact(4).map(Quat::from_slice).collect()),
        };
        let interpolation = match sampler.interpolation() {
            I::Linear => Interpolation::Linear,
            I::Step => Interpolation::Step,
            I::CubicSpline => Interpolation::CubicSpline,
        };
        out.channels.push(Channel {
            node,
            times,
            keys,
            interpolation,
        });
    }
    Ok(out)
}

fn gltf_error(file: &str, element: &str, reason: String) -> SceneError {
    SceneError::Gltf {
        file: file.to_string(),
        element: element.to_string(),
        reason,
    }
}

fn load_buffers(gltf: &gltf::Gltf, name: &str, base: Option<&Path>) -> Result<Buffers, SceneError> {
    let mut out = Vec::new();
    let mut total = 0usize;
    for buffer in gltf.buffers() {
        let element = format!("buffer {}", buffer.index());
        total = total.saturating_add(buffer.length());
        if total > MAX_BUFFER_BYTES {
            return Err(gltf_error(
                name,
                &element,
                format!("buffers declare more than the {MAX_BUFFER_BYTES} byte limit in all"),
            ));
        }
        let data = match buffer.source() {
            // glTF 2.0, 4.4.3.3: only the first buffer may be the GLB's
            // binary chunk.
            gltf::buffer::Source::Bin if buffer.index() != 0 => {
                return Err(gltf_error(
                    name,
                    &element,
                    "only buffer 0 may refer to the GLB binary chunk".into(),
                ));
            }
            gltf::buffer::Source::Bin => gltf
                .blob
                .as_deref()
                .map(|b| b[..b.len().min(buffer.length())].to_vec())
                .ok_or_else(|| {
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
    Ok(Buffers {
        data: out,
        read: std::cell::Cell::new(0),
    })
}

fn primitive_mesh(
    prim: &gltf::Primitive<'_>,
    buffers: &Buffers,
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
    let n = positions.len();
    let attribute = |sem: Semantic, dims: Dimensions| -> Result<Option<Vec<f32>>, SceneError> {
        let Some(a) = prim.get(&sem) else {
            return Ok(None);
        };
        let what = sem.to_string();
        if a.dimensions() != dims {
            return Err(gltf_error(
                name,
                element,
                format!(
                    "{what} accessor {} is {:?}, expected {dims:?}",
                    a.index(),
                    a.dimensions()
                ),
            ));
        }
        let f = read(a, &what)?.floats();
        if f.len() != n * dims.multiplicity() {
            return Err(gltf_error(
                name,
                element,
                format!("{what} and POSITION counts differ"),
            ));
        }
        Ok(Some(f))
    };
    if prim.get(&Semantic::Joints(1)).is_some() || prim.get(&Semantic::Weights(1)).is_some() {
        return Err(gltf_error(
            name,
            element,
            "more than four joints per vertex (JOINTS_1) is not supported".into(),
        ));
    }
    let skin = match (
        attribute(Semantic::Joints(0), Dimensions::Vec4)?,
        attribute(Semantic::Weights(0), Dimensions::Vec4)?,
    ) {
        (Some(j), Some(w)) => {
            if let Some(bad) = j
                .iter()
                .find(|&&x| !(0.0..=65535.0).contains(&x) || x.fract() != 0.0)
            {
                return Err(gltf_error(
                    name,
                    element,
                    format!("joint index {bad} is not a u16"),
                ));
            }
            if let Some(bad) = w.iter().find(|&&x| !x.is_finite() || x < 0.0) {
                return Err(gltf_error(
                    name,
                    element,
                    format!("joint weight {bad} is negative or not finite"),
                ));
            }
            Some(SkinWeights {
                joints: j
                    .chunks_exact(4)
                    .map(|c| [c[0] as u16, c[1] as u16, c[2] as u16, c[3] as u16])
                    .collect(),
                weights: w
                    .chunks_exact(4)
                    .map(|c| [c[0], c[1], c[2], c[3]])
                    .collect(),
            })
        }
        (None, None) => None,
        _ => {
            return Err(gltf_error(
                name,
                element,
                "JOINTS_0 without WEIGHTS_0 or the other way round".into(),
            ));
        }
    };
    let material = prim.material();
    let alpha = match material.alpha_mode() {
        gltf::material::AlphaMode::Mask => {
            let pbr = material.pbr_metallic_roughness();
            if let Some(t) = pbr.base_color_texture() {
                return Err(gltf_error(
                    name,
                    &format!(
                        "material {}",
                        material.index().map_or("default".into(), |i| i.to_string())
                    ),
                    format!(
                        "alpha mask from texture {} is not supported (factor and COLOR_0 masks are)",
                        t.texture().index()
                    ),
                ));
            }
            let vertex_alpha = match prim.get(&Semantic::Colors(0)) {
                Some(a) if a.dimensions() == Dimensions::Vec4 => {
                    attribute(Semantic::Colors(0), Dimensions::Vec4)?
                        .unwrap_or_default()
                        .chunks_exact(4)
                        .map(|c| c[3])
                        .collect()
                }
                _ => Vec::new(),
            };
            Some(AlphaMask {
                cutoff: material.alpha_cutoff().unwrap_or(0.5),
                factor: pbr.base_color_factor()[3],
                vertex_alpha,
                texture: None,
            })
        }
        _ => None,
    };
    Ok(Mesh {
        positions,
        normals,
        indices,
        double_sided: material.double_sided(),
        skin,
        alpha,
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
    normalized: bool,
}

impl Elements {
    /// Every component as f32: floats as they are, normalized integers
    /// mapped to [0, 1] or [-1, 1] (glTF 2.0, 3.11), other integers as
    /// their value.
    fn floats(&self) -> Vec<f32> {
        use gltf::accessor::DataType;
        let b = &self.bytes;
        let n = self.normalized;
        match self.kind {
            DataType::F32 => b
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            DataType::U32 => b
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32)
                .collect(),
            DataType::U8 => b
                .iter()
                .map(|&c| if n { c as f32 / 255.0 } else { c as f32 })
                .collect(),
            DataType::I8 => b
                .iter()
                .map(|&c| {
                    let c = c as i8 as f32;
                    if n { (c / 127.0).max(-1.0) } else { c }
                })
                .collect(),
            DataType::U16 => b
                .chunks_exact(2)
                .map(|c| {
                    let c = u16::from_le_bytes([c[0], c[1]]) as f32;
                    if n { c / 65535.0 } else { c }
                })
                .collect(),
            DataType::I16 => b
                .chunks_exact(2)
                .map(|c| {
                    let c = i16::from_le_bytes([c[0], c[1]]) as f32;
                    if n { (c / 32767.0).max(-1.0) } else { c }
                })
                .collect(),
        }
    }

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
fn read_accessor(acc: &gltf::Accessor<'_>, buffers: &Buffers) -> Result<Elements, String> {
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
        .data
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
    let read = buffers
        .read
        .get()
        .saturating_add(count.saturating_mul(size));
    if read > MAX_ACCESSOR_BYTES {
        return Err(format!(
            "accessors would read more than the {MAX_ACCESSOR_BYTES} byte limit in all"
        ));
    }
    buffers.read.set(read);
    let mut bytes = Vec::with_capacity(count * size);
    for k in 0..count {
        let at = start + k * stride;
        bytes.extend_from_slice(&data[at..at + size]);
    }
    Ok(Elements {
        bytes,
        size,
        kind: acc.data_type(),
        normalized: acc.normalized(),
    })
}
