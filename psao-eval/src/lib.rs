//! # psao-eval
//!
//! The end of the data path, and the truth it is measured against: what a
//! client's pixels are and what they should be.
//!
//! - [`View`]: a camera seen through an image, the one pixel convention
//!   every pass shares;
//! - [`PosedScene`] and [`GBuffer`]: the scene at a time, and its
//!   primary-ray G-buffer (position, normal, depth, instance);
//! - [`ray_traced_ao`]: AO traced at every pixel, the reference at many
//!   rays per pixel and RTAO at a few;
//! - [`psao_image`]: the PSAO client's image, reconstructed per pixel from
//!   a [`psao_codec::Mirror`] (paper eq. 2-4), and [`open_reasons`]: why
//!   it left a pixel open where the reference is dark;
//! - [`sao`]: scalable ambient obscurance, the screen-space baseline;
//! - [`rmse`], [`psnr`], [`ssim`] and [`error_map`]: image metrics.
//!
//! It builds on psao-scene (scenes and the CPU tracer) and psao-codec (the
//! mirror); nothing upstream depends on it.

mod coverage;
mod gbuffer;
mod metrics;
mod open_pixels;
mod pixel_ao;
mod sao;
mod view;

pub use coverage::path_coverage;
pub use gbuffer::{GBuffer, NO_INSTANCE, PosedScene};
pub use metrics::{MetricError, error_map, psnr, rmse, ssim};
pub use open_pixels::{
    Cause, OpenCause, OpenReasons, REFERENCE_DARK, SHOWN_OPEN, open_cause, open_reasons,
};
pub use pixel_ao::{ClientImage, psao_image, psao_image_seen, ray_traced_ao};
pub use sao::{SaoParams, sao};
pub use view::{MAX_IMAGE_SIDE, View};
