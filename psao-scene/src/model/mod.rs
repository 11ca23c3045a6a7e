//! The scene model, where the data path starts: triangle meshes
//! ([`mesh`]), optionally skinned ([`skin`]), morphed ([`morph`]) or
//! alpha-masked ([`alpha`]),
//! placed as instances in a [`scene`] with a node hierarchy ([`node`]),
//! keyframed node animations ([`animation`]) and a camera path
//! ([`camera`]); [`pose`] evaluates it all at a time (node and instance
//! transforms, joint matrices, skinned vertices), which is what the later
//! stages (points, AO, the pipeline) read.

pub(crate) mod alpha;
pub(crate) mod animation;
pub(crate) mod camera;
pub(crate) mod mesh;
pub(crate) mod morph;
pub(crate) mod node;
pub(crate) mod pose;
pub(crate) mod scene;
pub(crate) mod skin;
