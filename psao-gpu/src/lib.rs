//! # psao-gpu
//!
//! PSAO on the GPU with wgpu ray queries (Vulkan): acceleration structures
//! built from a [`psao_scene::Scene`] ([`GpuScene`]: one BLAS per mesh, one
//! per skinned instance rebuilt as it deforms, a TLAS of the instances
//! placed by their transforms) and point AO ([`GpuAo`]) that samples,
//! estimates and offsets rays exactly as the CPU backend
//! ([`psao_scene::AoTracer`]) does, both estimators; and, for clients, the
//! mirror on the GPU ([`GpuMirror`], uploaded whole or by changed ranges)
//! with the reconstruction in WGSL ([`RECONSTRUCT_WGSL`], to include in a
//! renderer's shaders, or as a compute pass over a G-buffer:
//! [`GpuReconstruct`]).
//!
//! The SAO baseline runs on the same device ([`GpuSao`], the passes of
//! [`psao_eval::sao`]), so the reconstruction can be timed against it.
//!
//! Without a Vulkan driver with ray queries, [`GpuContext::new`] returns a
//! [`GpuError`] that says what to install (on a machine without a GPU:
//! Mesa's lavapipe); nothing panics, and the other crates do not need this
//! one.
//!
//! A server pipeline traces on the GPU with [`GpuBackend`]
//! ([`psao_scene::Pipeline::with_backend`]). It also compares the new AO
//! with what clients hold on the GPU ([`GpuAo::trace_changed`]: the
//! paper's thresholds, with the changed points and cells compacted with
//! atomics), so only the points worth sending are read back.

mod accel;
mod alpha;
mod ao;
mod backend;
mod context;
mod error;
mod mirror;
mod reconstruct;
mod sao;

pub use accel::{GpuScene, TriangleOrder};
pub use ao::GpuAo;
pub use backend::GpuBackend;
pub use context::GpuContext;
pub use error::GpuError;
pub use mirror::{GpuMirror, MAX_GPU_INSTANCE_ID};
pub use reconstruct::{GpuReconstruct, RECONSTRUCT_WGSL};
pub use sao::{GpuSao, PassTimes};
