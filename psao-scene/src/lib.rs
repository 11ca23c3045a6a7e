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

mod ao;
mod default_scene;
mod error;
mod gltf_import;
mod layout;
mod pipeline;
mod points;
mod random;
mod scene;

pub use ao::{AoParams, AoResult, AoTracer, Estimator, MAX_RAYS, morton_order, ray_offset};
pub use default_scene::{MOVING_BOX, default_scene};
pub use error::SceneError;
pub use gltf_import::{MAX_BUFFER_BYTES, load_gltf, load_gltf_slice};
pub use layout::{LayoutParams, layout};
pub use pipeline::{FrameReport, Motion, Pipeline, PipelineConfig};
pub use points::{MAX_SPAWNED_POINTS, PointSet, eliminate, generate_points};
pub use random::{hash, uniform};
pub use scene::{Instance, Mesh, Scene, transformed_bounds};
