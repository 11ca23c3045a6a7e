//! The client half: the mirror on the GPU and the reconstruction per
//! pixel. Needs compute shaders and storage buffers only (no ray queries,
//! no scene), so it runs on a renderer's own device
//! ([`GpuContext::from_device`](crate::GpuContext::from_device)), on GPUs
//! without RT cores and under WebGPU's limits.

pub(crate) mod gbuffer;
pub(crate) mod mirror;
pub(crate) mod reconstruct;
