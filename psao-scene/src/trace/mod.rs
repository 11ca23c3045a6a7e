//! AO, the third stage of the data path (paper 3.3): CPU ray tracing with
//! obvhs of the ambient occlusion at points. [`geometry`] holds what rays
//! are traced against (triangles with alpha masks, BVHs over them, BVHs
//! placed in the world as layers); [`top`] the BVH over the layers' world
//! boxes that rays go through first; [`ao`] the tracer itself (parameters,
//! the closest-hit and Laine-Karras estimators, results, and which traced
//! points changed enough to send); [`open`] the test that finds a point
//! whose rays can hit nothing, open without a ray cast.

pub(crate) mod ao;
pub(crate) mod geometry;
pub(crate) mod open;
pub(crate) mod top;
