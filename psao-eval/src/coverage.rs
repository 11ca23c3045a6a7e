//! How much of the picture a camera path fills: the share of pixels whose
//! primary ray meets geometry, frame by frame. A bench whose camera sees
//! little of the scene measures little of it.

use psao_scene::{Scene, SceneError};

use crate::gbuffer::PosedScene;
use crate::view::View;

/// The share of pixels covered at each of `times` along the scene's
/// camera path, in a `width x height` picture (the scene posed at each
/// time, back faces of single-sided materials culled as the G-buffer
/// does). A scene without a camera path is an error.
pub fn path_coverage(
    scene: &Scene,
    times: &[f32],
    width: u32,
    height: u32,
) -> Result<Vec<f64>, SceneError> {
    let path = scene.camera.as_ref().ok_or_else(|| SceneError::Camera {
        reason: "the scene has no camera path".into(),
    })?;
    times
        .iter()
        .map(|&t| {
            let view = View::new(path.at(t), width, height)?;
            let g = PosedScene::new(scene, t)?.gbuffer(&view);
            Ok(g.covered() as f64 / g.pixels().max(1) as f64)
        })
        .collect()
}
