//! # psao-scene
//!
//! The server side of PSAO without a GPU: a scene model ([`Scene`],
//! [`Mesh`]), point generation with weighted sample elimination
//! ([`generate_points`], paper 3.1), grid layout ([`layout`], paper 3.2) and
//! CPU ray-traced AO for points with obvhs ([`AoTracer`], paper 3.3), with
//! both the closest-hit and the Laine-Karras estimator.
//!
//! It also holds the embedded [`default_scene`] and the server frame
//! [`Pipeline`] for rigid motion (transforms, re-tracing only what motion
//! reaches, thresholds, encoding). Skins, node animation and glTF import
//! come next.

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
mod random;
mod scene;
mod skin;

pub use alpha::{AlphaMask, AlphaTexture};
pub use animation::{Animation, Channel, Interpolation, Keys};
pub use ao::{
    AoParams, AoResult, AoTracer, Estimator, Geometry, Layer, MAX_RAYS, TriangleBvh, TriangleMask,
    morton_order, ray_offset,
};
pub use camera::{Camera, CameraKey, CameraPath, Frustum};
pub use default_scene::{MOVING_BOX, TRELLIS, WALKER, default_scene};
pub use error::SceneError;
pub use gltf_import::{MAX_BUFFER_BYTES, load_gltf, load_gltf_slice};
pub use layout::{LayoutParams, layout};
pub use node::{Node, Trs, compose};
pub use pipeline::{FrameReport, Pipeline, PipelineConfig, ViewerCull};
pub use points::{Anchor, MAX_SPAWNED_POINTS, PointSet, eliminate, generate_points};
pub use pose::Pose;
pub use random::{hash, uniform};
pub use scene::{Instance, Mesh, Scene, transformed_bounds};
pub use skin::{Skin, SkinWeights};
