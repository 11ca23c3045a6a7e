//! # psao-gpu
//!
//! PSAO on the GPU with wgpu, in two halves that need different devices:
//!
//! - **Client** (always built; needs compute shaders and storage buffers
//!   only, [`GpuContext::CLIENT_FEATURES`] within
//!   [`GpuContext::client_limits`]): the mirror on the GPU ([`GpuMirror`],
//!   uploaded whole or by changed ranges) and the reconstruction in WGSL
//!   ([`RECONSTRUCT_WGSL`], to include in a renderer's shaders, or as a
//!   compute pass over a G-buffer: [`GpuReconstruct`], reading
//!   [`GBufferSlices`]). A renderer hands in its own device and queue
//!   ([`GpuContext::from_device`]); [`GpuContext::new_client`] opens one.
//!   It depends on psao-codec and wgpu, not on psao-scene.
//! - **Server** (feature `server`, on by default; needs ray queries,
//!   [`GpuContext::SERVER_FEATURES`], opened by [`GpuContext::new`]):
//!   acceleration structures built from a `psao_scene::Scene` (`GpuScene`:
//!   one BLAS per mesh, one per skinned instance rebuilt as it deforms, a
//!   TLAS of the instances placed by their transforms) and point AO
//!   (`GpuAo`) that samples, estimates and offsets rays exactly as the CPU
//!   backend (`psao_scene::AoTracer`) does, both estimators. A server
//!   pipeline traces on the GPU with `GpuBackend`
//!   (`psao_scene::Pipeline::with_backend`); it also compares the new AO
//!   with what clients hold on the GPU (`GpuAo::trace_changed`: the paper's
//!   thresholds, with the changed points and cells compacted with atomics),
//!   so only the points worth sending are read back. With
//!   `GpuBackend::with_single_rays` it casts the single rays the pipeline
//!   asks for instead (`GpuAo::cast_rays`), so that ray scores are kept as
//!   on the CPU: ray reuse, early decisions and the ray budget's prices
//!   then follow the CPU's rules.
//! - **Baseline** (feature `baseline`, on by default): SAO on the same
//!   device (`GpuSao`, the passes of `psao_eval::sao`, no ray queries), so
//!   that the reconstruction can be timed against it.
//!
//! Without a usable driver, [`GpuContext::new`] returns a [`GpuError`] that
//! says what to install (on a machine without a GPU: Mesa's lavapipe), and
//! the server half on a device without ray queries returns
//! [`GpuError::NoRayQuery`]; nothing panics, and the other crates do not
//! need this one.

mod client;
mod context;
mod error;
#[cfg(feature = "baseline")]
mod sao;
#[cfg(feature = "server")]
mod server;

pub use client::gbuffer::{GBufferSlices, NO_INSTANCE};
pub use client::mirror::{GpuMirror, MAX_GPU_INSTANCE_ID};
pub use client::reconstruct::{GpuReconstruct, RECONSTRUCT_SEEN_WGSL, RECONSTRUCT_WGSL};
pub use context::{GpuContext, PassTimes};
pub use error::GpuError;
#[cfg(feature = "baseline")]
pub use sao::GpuSao;
#[cfg(feature = "server")]
pub use server::{
    accel::GpuScene, accel::TriangleOrder, ao::GpuAo, ao::JOB_CHUNK, backend::GpuBackend,
};
