//! # psao-scene
//!
//! The start of the data path, on the server without a GPU: scene ->
//! points -> AO -> dirty set -> frames. (The pixels at the other end, and
//! the ray-traced truth they are measured against, are `psao-eval`.)
//!
//! The crate's folders follow that path:
//! - `model/`, the scene model ([`Scene`]): meshes ([`Mesh`], optionally
//!   skinned with [`SkinWeights`] or alpha-masked with [`AlphaMask`]),
//!   instances, a node hierarchy ([`Node`], [`Trs`]), skins ([`Skin`]),
//!   keyframed node animations ([`Animation`]: step, linear with slerp,
//!   cubic spline) and a camera path ([`CameraPath`]); [`Scene::pose`]
//!   evaluates it at a time;
//! - `import/`, glTF 2.0 import ([`load_gltf`]) of meshes, nodes, skins,
//!   animations and alpha-mask materials into that model, Wavefront OBJ
//!   import ([`load_obj`]), and [`load_scene_file`], which picks by
//!   extension;
//! - `points/`, point generation with weighted sample elimination
//!   ([`generate_points`], paper 3.1), each point anchored to its triangle
//!   so skinning carries it, and grid layout ([`layout`], paper 3.2);
//! - `trace/`, CPU ray-traced AO for points with obvhs ([`AoTracer`], paper
//!   3.3), with the closest-hit and the Laine-Karras estimators, over
//!   placed BVH [`Layer`]s (static geometry built once, moving instances
//!   placed by their transform, skinned ones refitted), and the points
//!   whose AO changed enough to send ([`ChangedPoints`]);
//! - `pipeline/`, the server frame [`Pipeline`]: animate, skin, choose what
//!   motion can reach (and, per viewer, what is in view), trace (on the
//!   CPU, or on any [`AoBackend`]), apply the thresholds (the dirty set),
//!   encode the frame;
//! - `scenes/`, the embedded [`default_scene`] and [`cesium_man_scene`],
//!   the procedural [`hall_scene`] (a large interior with many moving
//!   props and walking figures), and [`stage`] (a glTF model on a floor
//!   with an orbiting camera).
//!
//! Shared by the stages: errors ([`SceneError`], `error.rs`), the f32
//! precision checks ([`check_precision`], `precision.rs`) and counter-based
//! random numbers ([`uniform`], `random.rs`).
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

mod error;
pub mod export;
mod import;
mod model;
mod morton;
mod pipeline;
mod points;
mod precision;
mod random;
mod scenes;
mod trace;

pub use error::{SceneError, check_param};
pub use import::obj::{MAX_MTL_BYTES, MAX_MTL_FILES, MAX_OBJ_BYTES, load_obj, load_obj_slice};
pub use import::{
    MAX_ACCESSOR_BYTES, MAX_BUFFER_BYTES, MAX_INSTANCES, MAX_MORPH_BYTES, MAX_MORPH_TARGETS,
    MAX_SKINNED_VERTICES, load_gltf, load_gltf_slice, load_scene_file,
};
pub use model::alpha::{AlphaMask, AlphaTexture};
pub use model::animation::{Animation, Channel, Interpolation, Keys};
pub use model::camera::{
    Camera, CameraKey, CameraPath, DEFAULT_FOV_DEGREES, Frustum, MAX_CAMERA_KEYS,
    MAX_CAMERA_PATH_BYTES,
};
pub use model::mesh::{Mesh, bounds_of, transformed_bounds};
pub use model::morph::MorphTargets;
pub use model::node::{Node, Trs, compose};
pub use model::pose::{Pose, normal_matrix};
pub use model::scene::{Instance, MIN_TRANSFORM_RATIO, Scene, invertible};
pub use model::skin::{Skin, SkinWeights};
pub use morton::morton_order;
pub use pipeline::backend::{AoBackend, RayJob};
pub use pipeline::config::{
    DEFAULT_MAX_POINTS, EarlyDecisions, MoversWhole, POSE_DEPENDENT_SHARE, PipelineConfig,
    RayBudget, ViewerCull, Views,
};
pub use pipeline::early::EarlyAudit;
pub use pipeline::report::{FrameReport, TracePhases};
pub use pipeline::{Pipeline, SetupProgress, SetupStage};
pub use points::generate::{
    Anchor, MAX_SPAWNED_POINTS, MIN_SPAWNED, PointSet, TILE_POINTS, eliminate, generate_points,
    generate_points_with,
};
pub use points::layout::{LayoutParams, fit_to_points, layout};
pub use precision::{
    MAX_ULP_PER_AO_RADIUS, MAX_ULP_PER_POINT_SPACING, check_precision, f32_spacing,
};
pub use random::{hash, uniform};
pub use scenes::default_scene::{MOVING_BOX, TRELLIS, WALKER, cesium_man_scene, default_scene};
pub use scenes::hall::{HallParams, hall, hall_scene, hall_table};
pub use scenes::stage::{
    AZIMUTHS, FLOOR_MARGIN_EXTENTS, INTERIOR_SHARE, ORBIT_SECONDS, PROBE_RAYS, SWING, Setting,
    front_share, setting, stage,
};
pub use trace::ao::{
    AoParams, AoResult, AoTracer, ChangedPoints, Estimator, MAX_RAYS, PointRays, RAY_SUM_LANES,
    ao_of_scores, ray_offset,
};
pub use trace::geometry::{Geometry, Layer, TriangleBvh, TriangleMask, barycentric};
