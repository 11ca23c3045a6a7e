//! The embedded scenes, built from the model at the start of the data
//! path: the [`default_scene`] courtyard (and its CesiumMan character, also
//! on its own), the [`hall_scene`] interior with many moving parts, and
//! [`stage`], which sets an imported model on a floor with a camera
//! orbiting it.
//!
//! [`hall_scene`]: crate::hall_scene
//! [`stage`]: crate::stage

pub(crate) mod default_scene;
pub(crate) mod hall;
pub(crate) mod stage;
