//! psao-scene's server pipeline as a [`FrameSource`] (feature `scene`):
//! `serve(Pipeline::new(scene, config)?, ...)` streams a scene.

use glam::Affine3A;
use psao_codec::EncodedFrame;
use psao_scene::{Camera, Pipeline, Views};

use crate::source::{ClientViews, FrameSource, SourceError, SourceInfo, StepReport};

impl FrameSource for Pipeline {
    fn info(&self) -> SourceInfo {
        let enc = self.config().encoder;
        SourceInfo {
            compression: enc.compression.id(),
            max_frame_bytes: enc.limits.max_frame_bytes,
            max_payload_bytes: enc.limits.max_payload_bytes,
            mirror_bytes: (0..self.instance_count())
                .filter_map(|i| self.table(i))
                .map(|t| t.def().mirror_bytes() as u64)
                .sum(),
            point_format: (0..self.instance_count())
                .filter_map(|i| self.table(i))
                .map(|t| t.def().point_format)
                .max()
                .unwrap_or(0),
            overflow: (0..self.instance_count())
                .filter_map(|i| self.table(i))
                .any(|t| t.def().overflow),
            culls: self.config().cull.is_some(),
        }
    }

    fn step(&mut self, dt: f32) -> Result<(Option<EncodedFrame>, StepReport), SourceError> {
        let (frame, report) = Pipeline::step(self, dt)?;
        let report = StepReport {
            traced: report.traced,
            updated: report.updated,
            culled: report.culled,
            waiting: report.waiting,
            oldest_wait: report.oldest_wait,
            wait_bound: report.wait_bound,
        };
        Ok((frame, report))
    }

    fn keyframe(&mut self) -> Result<EncodedFrame, SourceError> {
        Ok(Pipeline::keyframe(self)?)
    }

    fn place(&mut self, instance: u32, transform: Affine3A) -> Result<(), SourceError> {
        Ok(self.place_instance(instance as usize, transform)?)
    }

    /// The union of the clients' frusta, built with the pipeline's
    /// [`ViewerCull`](psao_scene::ViewerCull) planes.
    fn set_views(&mut self, views: ClientViews<'_>) {
        let Some(cull) = self.config().cull else {
            return;
        };
        let views = match views {
            ClientViews::All => Views::All,
            ClientViews::Poses(poses) => Views::Frusta(
                poses
                    .iter()
                    .map(|pose| {
                        let camera = Camera {
                            eye: pose.eye,
                            target: pose.target,
                            fov_y: pose.fov_y,
                        };
                        camera.frustum(pose.aspect, cull.near(), cull.far)
                    })
                    .collect(),
            ),
        };
        Pipeline::set_views(self, views);
    }
}
