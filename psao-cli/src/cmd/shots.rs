//! The AO images `psao demo` (direct or through relays) writes from a
//! client's mirror along the camera path.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context as _;
use psao_eval::{PosedScene, View, psao_image};
use psao_scene::Scene;

use crate::bench::images::{ao_png16, composite};

/// The AO images `psao demo` writes: what the first client shows at
/// moments of the camera path, reconstructed from its mirror on a
/// G-buffer of the scene at that moment (the client renders the scene
/// itself and takes AO from the mirror, as a split renderer does).
pub struct Shots {
    count: u32,
    taken: u32,
    out: PathBuf,
    /// The scene, with its camera path.
    pub scene: Arc<Scene>,
}

/// Size of the demo's images.
const SHOT_SIZE: (u32, u32) = (480, 270);

impl Shots {
    /// `count` images of `scene` into `out` (created now, so a bad path
    /// fails early).
    pub fn new(count: u32, out: PathBuf, scene: Scene) -> anyhow::Result<Shots> {
        if count > 0 {
            std::fs::create_dir_all(&out)
                .with_context(|| format!("cannot create {}", out.display()))?;
        }
        Ok(Shots {
            count,
            taken: 0,
            out,
            scene: Arc::new(scene),
        })
    }

    /// Whether the next image is due after `frames` of `total`: images
    /// fall at the ends of `count` equal parts of the run.
    pub fn due(&self, frames: u64, total: u64) -> bool {
        self.taken < self.count && frames * self.count as u64 >= total * (self.taken as u64 + 1)
    }

    /// Renders and writes the image at scene time `t` from `mirror`;
    /// returns a line saying where it went.
    pub async fn take(&mut self, mirror: psao_codec::Mirror, t: f32) -> anyhow::Result<String> {
        self.taken += 1;
        let (scene, out, k) = (self.scene.clone(), self.out.clone(), self.taken);
        tokio::task::spawn_blocking(move || -> anyhow::Result<String> {
            let path = scene
                .camera
                .as_ref()
                .context("the scene has no camera path")?;
            let view = View::new(path.at(t), SHOT_SIZE.0, SHOT_SIZE.1)?;
            let posed = PosedScene::new(&scene, t)?;
            let g = posed.gbuffer(&view);
            let image = psao_image(&mirror, &g)?;
            let ao = out.join(format!("demo-{k:02}-ao.png"));
            ao_png16(&image.ao, view.width, view.height)
                .save(&ao)
                .with_context(|| ao.display().to_string())?;
            let lit = out.join(format!("demo-{k:02}-lit.png"));
            image::RgbImage::from_raw(view.width, view.height, composite(&g, &image.ao))
                .context("image size")?
                .save(&lit)
                .with_context(|| lit.display().to_string())?;
            Ok(format!(
                "image {k}: t = {t:.2} s, AO from the client's mirror (sequence {}) -> {} and {}",
                mirror.sequence().map_or("none".into(), |s| s.to_string()),
                ao.display(),
                lit.display()
            ))
        })
        .await
        .context("image task")?
    }
}
