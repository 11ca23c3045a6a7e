//! # psao-scene
//!
//! The server side of PSAO without a GPU: a scene model ([`Scene`],
//! [`Mesh`]), point generation with weighted sample elimination
//! ([`generate_points`], paper 3.1), grid layout ([`layout`], paper 3.2) and
//! CPU ray-traced AO for points with obvhs ([`AoTracer`], paper 3.3), with
//! both the closest-hit and the Laine-Karras estimator.
//!
//! This is the first slice of issue 3: static scenes only (skins, node
//! animation, glTF import, the embedded default scene and the frame
//! pipeline come next).

mod ao;
mod error;
mod layout;
mod points;
mod random;
mod scene;

pub use ao::{AoParams, AoResult, AoTracer, Estimator, MAX_RAYS, morton_order};
pub use error::SceneError;
pub use layout::{LayoutParams, layout};
pub use points::{MAX_SPAWNED_POINTS, PointSet, eliminate, generate_points};
pub use random::{hash, uniform};
pub use scene::{Instance, Mesh, Scene};
