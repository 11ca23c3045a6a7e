//! Errors of the GPU backend: each says what is missing and what to do.

use thiserror::Error;

/// What went wrong on the GPU side.
#[derive(Clone, Debug, Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No usable adapter at all.
    #[error(
        "no usable GPU adapter: {details}; install a Vulkan driver (on a machine without a GPU: Mesa's lavapipe, package mesa-vulkan-drivers, 25 or later for ray queries, e.g. from Debian bookworm-backports)"
    )]
    NoAdapter {
        /// What wgpu said.
        details: String,
    },
    /// A Vulkan adapter, but without ray queries.
    #[error(
        "no Vulkan adapter with ray queries: `{adapter}` ({driver}) lacks VK_KHR_ray_query / VK_KHR_acceleration_structure; update the driver (Mesa 25 or later for lavapipe) or use a GPU that has them"
    )]
    NoRayQuery {
        /// The adapter's name.
        adapter: String,
        /// Its driver and version.
        driver: String,
    },
    /// The device could not be created.
    #[error("cannot open the GPU device: {0}")]
    Device(String),
    /// The device was lost (driver reset, out of memory).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
    /// wgpu rejected a call (validation or out of memory), naming what.
    #[error("GPU {what} failed: {details}")]
    Rejected {
        /// The step.
        what: &'static str,
        /// wgpu's message.
        details: String,
    },
    /// The device's limits are too small for the scene.
    #[error("the GPU's limits are too small: {what} needs {needed}, the device allows {limit}")]
    Limits {
        /// What.
        what: &'static str,
        /// Needed.
        needed: u64,
        /// Allowed.
        limit: u64,
    },
    /// The scene has something the GPU backend does not do yet.
    #[error("not supported on the GPU backend yet: {0}")]
    Unsupported(String),
    /// Inputs that do not fit together.
    #[error("bad input: {0}")]
    Input(String),
    /// A scene error (validation, pose, SAO inputs).
    #[cfg(any(feature = "server", feature = "baseline"))]
    #[error(transparent)]
    Scene(#[from] psao_scene::SceneError),
}
