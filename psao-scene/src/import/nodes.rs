//! The node side of a glTF scene: its node hierarchy (parents before
//! children, each with its translation, rotation and scale), the mesh
//! instances hanging from the nodes (with their skins), skins and
//! node animations.

use std::collections::HashMap;

use glam::{Affine3A, Mat4, Quat, Vec3};

use super::buffers::{Buffers, read_accessor};
use super::mesh::primitive_mesh;
use super::{MAX_INSTANCES, gltf_error};
use crate::error::SceneError;
use crate::model::animation::{Animation, Channel, Interpolation, Keys};
use crate::model::camera::{CameraKey, CameraPath};
use crate::model::node::Trs;
use crate::model::scene::{Instance, Scene};
use crate::model::skin::Skin;

/// Adds the nodes of `scene` to `out` in depth-first order from the
/// scene's roots, so parents come before children. Returns `order`
/// (`order[gltf index]` is the node's index in `out`; `count` is the
/// file's number of nodes) and the glTF nodes in the order they were added.
pub(super) fn read_nodes<'a>(
    scene: &gltf::Scene<'a>,
    count: usize,
    name: &str,
    out: &mut Scene,
) -> Result<(Vec<Option<usize>>, Vec<gltf::Node<'a>>), SceneError> {
    let mut order: Vec<Option<usize>> = vec![None; count];
    let mut stack: Vec<(gltf::Node<'a>, Option<usize>, u32)> =
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
    Ok((order, visited))
}

/// Every primitive of the mesh of each of `visited` becomes an
/// [`Instance`] hanging from the node, with the node's skin (if any, and
/// if the primitive carries joints). Each mesh primitive and each skin is
/// read once, whatever the number of nodes that use it, except that a
/// node with weights of its own (or animated ones) gets its own copy. At most
/// [`MAX_INSTANCES`].
pub(super) fn read_instances(
    visited: &[gltf::Node<'_>],
    morphing: &std::collections::HashSet<usize>,
    buffers: &Buffers,
    name: &str,
    node_of: &dyn Fn(usize, &str) -> Result<usize, SceneError>,
    out: &mut Scene,
) -> Result<(), SceneError> {
    let mut skins: HashMap<usize, usize> = HashMap::new();
    let mut meshes: HashMap<(usize, usize, Option<usize>), usize> = HashMap::new();
    let mut morph_budget = super::mesh::MAX_MORPH_BYTES;
    for node in visited {
        let here = node_of(node.index(), "scene")?;
        let Some(mesh) = node.mesh() else { continue };
        let skin = match node.skin() {
            Some(sk) => Some(match skins.get(&sk.index()) {
                Some(&i) => i,
                None => {
                    let skin = read_skin(&sk, buffers, name, node_of)?;
                    out.skins.push(skin);
                    skins.insert(sk.index(), out.skins.len() - 1);
                    out.skins.len() - 1
                }
            }),
            None => None,
        };
        // Morph targets take the node's default weights, else the mesh's
        // (glTF 3.7.2.2); a node with weights of its own gets meshes of
        // its own.
        let weights = node.weights().or(mesh.weights()).unwrap_or(&[]);
        // A node whose weights an animation drives keeps the targets, in
        // meshes of its own.
        let animated = morphing.contains(&node.index());
        let own = (node.weights().is_some() || animated).then_some(node.index());
        for prim in mesh.primitives() {
            let key = (mesh.index(), prim.index(), own);
            let id = match meshes.get(&key) {
                Some(&id) => id,
                None => {
                    let element = format!("mesh {} primitive {}", mesh.index(), prim.index());
                    let m = primitive_mesh(
                        &prim,
                        weights,
                        animated,
                        &mut morph_budget,
                        buffers,
                        name,
                        &element,
                    )?;
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
    Ok(())
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
pub(super) fn read_animation(
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
        // One weight per target of the node's mesh, per key.
        let targets = target
            .node()
            .mesh()
            .and_then(|m| m.primitives().map(|p| p.morph_targets().len()).max())
            .unwrap_or(0);
        let want = match target.property() {
            Property::Rotation => gltf::accessor::Dimensions::Vec4,
            Property::MorphTargetWeights if targets == 0 => {
                return Err(gltf_error(
                    name,
                    &element,
                    "drives the morph weights of a node whose mesh has no morph targets".into(),
                ));
            }
            Property::MorphTargetWeights => gltf::accessor::Dimensions::Scalar,
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
            Property::MorphTargetWeights => Keys::Weights { targets, values: f },
            Property::Rotation => Keys::Rotation(f.chunks_exact(4).map(Quat::from_slice).collect()),
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

/// Most keys sampled from an animated camera node.
const MAX_CAMERA_SAMPLES: usize = 1800;

/// The scene's camera: the first node in scene order holding a
/// perspective camera (glTF names no active camera; orthographic ones are
/// skipped), as a camera path following the node's world transform,
/// looking down its -Z, sampled at 30 Hz over the animations when any
/// animation plays. `None` without a perspective camera. Call on a
/// validated scene.
pub(super) fn read_camera(
    visited: &[gltf::Node<'_>],
    node_of: &dyn Fn(usize, &str) -> Result<usize, SceneError>,
    out: &Scene,
) -> Result<Option<CameraPath>, SceneError> {
    let Some((node, yfov)) = visited.iter().find_map(|n| match n.camera()?.projection() {
        gltf::camera::Projection::Perspective(p) => Some((n.index(), p.yfov())),
        gltf::camera::Projection::Orthographic(_) => None,
    }) else {
        return Ok(None);
    };
    let ours = node_of(node, "camera")?;
    let span = out
        .animations
        .iter()
        .map(|a| a.duration())
        .filter(|d| d.is_finite())
        .fold(0.0f32, f32::max)
        .min(60.0);
    let samples = if span > 0.0 {
        ((span * 30.0).ceil() as usize).clamp(1, MAX_CAMERA_SAMPLES)
    } else {
        0
    };
    let mut keys = Vec::with_capacity(samples + 1);
    for k in 0..=samples {
        let time = if samples == 0 {
            0.0
        } else {
            span * k as f32 / samples as f32
        };
        let m = out.pose(time).nodes[ours];
        let eye = m.translation.into();
        let forward = m.transform_vector3(-Vec3::Z).normalize_or(-Vec3::Z);
        keys.push(CameraKey {
            time,
            eye,
            target: eye + forward,
        });
    }
    let path = CameraPath { keys, fov_y: yfov };
    path.validate()?;
    Ok(Some(path))
}
