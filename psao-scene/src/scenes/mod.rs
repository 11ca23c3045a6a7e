//! The embedded scenes, built from the model at the start of the data
//! path: the [`default_scene`] courtyard (and its CesiumMan character, also
//! on its own), and [`stage`], which sets an imported model on a floor
//! with a camera orbiting it.

pub(crate) mod default_scene;
pub(crate) mod stage;
