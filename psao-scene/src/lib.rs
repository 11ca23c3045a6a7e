//! # psao-scene
//!
//! The start of the data path, on the server without a GPU: scene ->
//! points -> AO -> dirty set -> frames. (The pixels at the other end, and
//! the ray-traced truth they are measured against, are `psao-eval`.)
//! - the scene model ([`Scene`]): meshes ([`Mesh`], optionally skinned with
//!   [`SkinWeights`] or alpha-masked with [`AlphaMask`]), instances, a node
//!   hierarchy ([`Node`], [`Trs`]), skins ([`Skin`]), keyframed node
//!   animations ([`Animation`]: step, linear with slerp, cubic spline) and a
//!   camera path ([`CameraPath`]); [`Scene::pose`] evaluates it at a time;
//! - glTF 2.0 import ([`load_gltf`]) of meshes, nodes, skins, animations and
//!   alpha-mask materials;
//! - point generation with weighted sample elimination ([`generate_points`],
//!   paper 3.1), each point anchored to its triangle so skinning carries it;
//! - grid layout ([`layout`], paper 3.2);
//! - CPU ray-traced AO for points with obvhs ([`AoTracer`], paper 3.3), with
//!   the closest-hit and the Laine-Karras estimators, over placed BVH
//!   [`Layer`]s (static geometry built once, moving instances placed by
//!   their transform, skinned ones refitted);
//! - the server frame [`Pipeline`]: animate, skin, choose what motion can
//!   reach (and, per viewer, what is in view), trace (on the CPU, or on any
//!   [`AoBackend`]), apply the thresholds (the dirty set), encode;
//! - the embedded [`default_scene`] and [`cesium_man_scene`], and
//!   [`stage`] (a glTF model on a floor with an orbiting camera).
//!
//! ## Numerical limits
//!
//! Positions are f32, whose spacing grows with the coordinate (0.0078 at
//! 1e5, 1 at 1e7). [`Pipeline::new`] (and [`Pipeline::place_instance`])
//! refuses, with [`SceneError::Precision`] naming the instance, the
//! coordinate, the spacing and the limit, a scene where that spacing at an
//! instance's largest coordinate (time 0; a skinned one over the poses its
//! grid covers) is above [`MAX_ULP_PER_AO_RADIUS`] (1/64) of the AO radius
//! in world space, or above [`MAX_ULP_PER_POINT_SPACING`] (1/2) of its
//! point spacing in local space (world positions counted in local units
//! through the inverse transform). With the paper's 0.6 m radius that
//! accepts coordinates up to 131,071 and refuses 1e7; see
//! [`check_precision`] for the measurements behind the bounds and
//! `spec/numerics.md`. Scale alone changes nothing: AO rays start a little
//! behind their origin so that the BVH's absolute 1e-4 box clamp loses no
//! hit in a scene millimetres across.

mod alpha;
mod animation;
mod ao;
mod camera;
mod default_scene;
mod error;
mod gltf_import;
mod layout;
mod node;
mod pipeline;
mod points;
mod pose;
mod precision;
mod random;
mod scene;
mod skin;
mod stage;

pub use alpha::{AlphaMask, AlphaTexture};
pub use animation::{Animation, Channel, Interpolation, Keys};
pub use ao::{
    AoParams, AoResult, AoTracer, ChangedPoints, Estimator, Geometry, Layer, MAX_RAYS,
    RAY_SUM_LANES, TriangleBvh, TriangleMask, barycentric, morton_order, ray_offset,
};
pub use camera::{Camera, CameraKey, CameraPath, Frustum};
pub use default_scene::{MOVING_BOX, TRELLIS, WALKER, cesium_man_scene, default_scene};
pub use error::{SceneError, check_param};
pub use gltf_import::{
    MAX_ACCESSOR_BYTES, MAX_BUFFER_BYTES, MAX_INSTANCES, MAX_SKINNED_VERTICES, load_gltf,
    load_gltf_slice,
};
pub use layout::{LayoutParams, layout};
pub use node::{Node, Trs, compose};
pub use pipeline::{AoBackend, FrameReport, Pipeline, PipelineConfig, ViewerCull, Views};
pub use points::{Anchor, MAX_SPAWNED_POINTS, PointSet, eliminate, generate_points};
pub use pose::{Pose, normal_matrix};
pub use precision::{
    MAX_ULP_PER_AO_RADIUS, MAX_ULP_PER_POINT_SPACING, check_precision, f32_spacing,
};
pub use random::{hash, uniform};
pub use scene::{Instance, Mesh, Scene, bounds_of, transformed_bounds};
pub use skin::{Skin, SkinWeights};
pub use stage::{FLOOR_MARGIN, ORBIT_SECONDS, stage};
