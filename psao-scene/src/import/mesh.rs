//! Mesh primitives: a triangle-list primitive's positions, indices,
//! normals (computed from the faces when missing) and joint weights become
//! a [`Mesh`], its material's alpha mask with it.

use glam::Vec3;
use gltf::mesh::Mode;

use super::buffers::{Buffers, read_accessor};
use super::gltf_error;
use super::material::alpha_mask;
use crate::error::SceneError;
use crate::model::mesh::Mesh;
use crate::model::morph::MorphTargets;

/// Most morph targets a primitive may have.
pub const MAX_MORPH_TARGETS: usize = 256;

/// Most bytes of animated morph target offsets over a whole file.
pub const MAX_MORPH_BYTES: usize = 1 << 30;
use crate::model::skin::SkinWeights;

/// The [`Mesh`] of a primitive, its morph targets applied with `weights`
/// (a missing weight is 0); with `animated`, the targets are kept as well
/// ([`MorphTargets`], rest weights `weights`) for an animation to drive.
/// `element` names it in errors. At most [`MAX_MORPH_TARGETS`] targets;
/// the targets kept draw on `morph_budget` (bytes left of
/// [`MAX_MORPH_BYTES`]), each at least 64 bytes however empty.
pub(super) fn primitive_mesh(
    prim: &gltf::Primitive<'_>,
    weights: &[f32],
    animated: bool,
    morph_budget: &mut usize,
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
    let mut positions = positions;
    // Morph target deltas, weighted (glTF 3.7.2.1): positions now, normals
    // once they are read.
    let mut normal_deltas: Vec<(f32, Vec<Vec3>)> = Vec::new();
    let mut morph = MorphTargets::default();
    let vertex_count = positions.len();
    let vec3_of =
        |a: Option<gltf::Accessor<'_>>, what: &str| -> Result<Option<Vec<Vec3>>, SceneError> {
            let Some(a) = a else { return Ok(None) };
            if a.data_type() != DataType::F32 || a.dimensions() != Dimensions::Vec3 {
                return Err(gltf_error(
                    name,
                    element,
                    format!("{what} accessor {} is not f32 VEC3", a.index()),
                ));
            }
            let v = read(a, what)?.vec3();
            if v.len() != vertex_count {
                return Err(gltf_error(
                    name,
                    element,
                    format!("{what} has {} values for {vertex_count} vertices", v.len()),
                ));
            }
            Ok(Some(v))
        };
    let targets = prim.morph_targets().len();
    if targets > MAX_MORPH_TARGETS {
        return Err(gltf_error(
            name,
            element,
            format!("{targets} morph targets, above {MAX_MORPH_TARGETS}"),
        ));
    }
    if animated {
        // Offsets kept per target: a position and a normal per vertex at
        // most (checked before anything is read).
        let cost = targets.saturating_mul((vertex_count.saturating_mul(24)).max(64));
        if cost > *morph_budget {
            return Err(gltf_error(
                name,
                element,
                format!(
                    "its animated morph targets would take {cost} bytes, above what is left of {MAX_MORPH_BYTES}"
                ),
            ));
        }
        *morph_budget -= cost;
    }
    for (k, target) in prim.morph_targets().enumerate() {
        let w = weights.get(k).copied().unwrap_or(0.0);
        if !w.is_finite() {
            return Err(gltf_error(
                name,
                element,
                format!("morph weight {k} is not finite"),
            ));
        }
        if animated {
            let p = vec3_of(target.positions(), "morph target POSITION")?.unwrap_or_default();
            let n = vec3_of(target.normals(), "morph target NORMAL")?.unwrap_or_default();
            for (q, d) in positions.iter_mut().zip(&p) {
                *q += w * *d;
            }
            // Normal offsets are applied from `morph.normals` below.
            morph.rest_weights.push(w);
            morph.positions.push(p);
            morph.normals.push(n);
            continue;
        }
        if w == 0.0 {
            continue;
        }
        // Applied at once: one target's deltas held at a time.
        if let Some(d) = vec3_of(target.positions(), "morph target POSITION")? {
            for (p, d) in positions.iter_mut().zip(d) {
                *p += w * d;
            }
        }
        if let Some(d) = vec3_of(target.normals(), "morph target NORMAL")? {
            normal_deltas.push((w, d));
        }
    }
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
    if !indices.len().is_multiple_of(3) {
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
            let mut n = read(a, "NORMAL")?.vec3();
            let kept = morph.rest_weights.iter().zip(&morph.normals);
            for (w, d) in normal_deltas.iter().map(|(w, d)| (w, d)).chain(kept) {
                for (n, d) in n.iter_mut().zip(d) {
                    *n += *w * *d;
                }
            }
            n.into_iter().map(|n| n.normalize_or(Vec3::Z)).collect()
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
    let alpha = alpha_mask(prim, name, &attribute)?;
    Ok(Mesh {
        positions,
        normals,
        indices,
        double_sided: prim.material().double_sided(),
        skin,
        morph: (animated && !morph.is_empty()).then_some(morph),
        alpha,
    })
}

/// Vertex normals as the area-weighted sum of the adjacent face normals.
pub(super) fn face_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
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
