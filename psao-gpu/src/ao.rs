//! Point AO with ray queries: the compute pass of `shaders/ao.wgsl`, which
//! samples, estimates and offsets rays exactly as psao-scene's CPU tracer
//! does, so that the same seed gives the same rays on both.

use psao_scene::{AoParams, AoResult, Estimator, morton_order};

use crate::accel::GpuScene;
use crate::context::{GpuContext, storage_layout, uniform_layout};
use crate::error::GpuError;

/// Threads per workgroup of the AO pass (the shader's `workgroup_size`).
const WORKGROUP: u32 = 64;

/// Most points traced in one dispatch (4 MiB of points: within every
/// device's storage binding limit, and short enough for a watchdog).
const CHUNK: usize = 1 << 18;

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    radius: f32,
    bias: f32,
    rays: u32,
    estimator: u32,
    seed_lo: u32,
    seed_hi: u32,
    count: u32,
    row: u32,
}

/// The AO compute pipeline.
#[derive(Debug)]
pub struct GpuAo {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl GpuAo {
    /// Compiles the AO pass.
    pub fn new(ctx: &GpuContext) -> Result<GpuAo, GpuError> {
        ctx.checked("AO shader compilation", || {
            let layout = ctx
                .device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("psao-gpu ao layout"),
                    entries: &[
                        wgpu::BindGroupLayoutEntry {
                            binding: 0,
                            visibility: wgpu::ShaderStages::COMPUTE,
                            ty: wgpu::BindingType::AccelerationStructure {
                                vertex_return: false,
                            },
                            count: None,
                        },
                        uniform_layout(1),
                        storage_layout(2, true),
                        storage_layout(3, true),
                        storage_layout(4, true),
                        storage_layout(5, false),
                        storage_layout(6, true),
                        storage_layout(7, true),
                    ],
                });
            let pipeline = ctx.compute_pipeline(
                "psao-gpu ao.wgsl",
                include_str!("shaders/ao.wgsl"),
                &[&layout],
            );
            GpuAo { pipeline, layout }
        })
    }

    /// AO at points with unit normals and stable ids against `scene`, with
    /// the CPU tracer's sampling ([`psao_scene::AoTracer::trace_ids`]):
    /// with the same parameters both trace the same rays. A non-finite
    /// point is open (1).
    pub fn trace_ids(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        ids: &[u32],
        points: &[glam::Vec3],
        normals: &[glam::Vec3],
        p: &AoParams,
    ) -> Result<AoResult, GpuError> {
        p.validate()?;
        if points.len() != normals.len() || points.len() != ids.len() {
            return Err(GpuError::Input(format!(
                "{} points, {} normals and {} ids",
                points.len(),
                normals.len(),
                ids.len()
            )));
        }
        let n = points.len();
        let rays = n as u64 * p.rays as u64;
        let Some(tlas) = scene.tlas().filter(|_| n > 0) else {
            return Ok(AoResult {
                ao: vec![1.0; n],
                rays,
            });
        };
        // Neighbouring invocations trace neighbouring points (coherent rays),
        // as the CPU backend does; results go back to input order below.
        let order = morton_order(points);
        let pts: Vec<[f32; 4]> = order
            .iter()
            .map(|&i| points[i].extend(0.0).to_array())
            .collect();
        let nrm: Vec<[f32; 4]> = order
            .iter()
            .map(|&i| normals[i].extend(0.0).to_array())
            .collect();
        let sorted_ids: Vec<u32> = order.iter().map(|&i| ids[i]).collect();
        // Bounded dispatches: within binding limits, and short enough for
        // a GPU's watchdog.
        let mut sorted = Vec::with_capacity(n);
        for start in (0..n).step_by(CHUNK) {
            let end = (start + CHUNK).min(n);
            sorted.extend(self.dispatch(
                ctx,
                scene,
                tlas,
                &pts[start..end],
                &nrm[start..end],
                &sorted_ids[start..end],
                p,
            )?);
        }
        let mut ao = vec![1.0f32; n];
        for (&i, &v) in order.iter().zip(&sorted) {
            ao[i] = v;
        }
        Ok(AoResult { ao, rays })
    }

    /// One dispatch over (sorted) points; AO in the same order.
    #[allow(clippy::too_many_arguments)]
    fn dispatch(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        tlas: &wgpu::Tlas,
        pts: &[[f32; 4]],
        nrm: &[[f32; 4]],
        sorted_ids: &[u32],
        p: &AoParams,
    ) -> Result<Vec<f32>, GpuError> {
        let n = pts.len();
        let grid = ctx.grid(n, WORKGROUP);
        let params = Params {
            radius: p.radius,
            bias: p.bias,
            rays: p.rays,
            estimator: match p.estimator {
                Estimator::ClosestHit => 0,
                Estimator::LaineKarras => 1,
            },
            seed_lo: p.seed as u32,
            seed_hi: (p.seed >> 32) as u32,
            count: n as u32,
            row: grid.0 * WORKGROUP,
        };
        let readback = ctx.checked("AO pass", || {
            let s = wgpu::BufferUsages::STORAGE;
            let uniform = ctx.buffer_with(
                "psao-gpu ao params",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM,
            );
            let pb = ctx.buffer_with("psao-gpu points", bytemuck::cast_slice(pts), s);
            let nb = ctx.buffer_with("psao-gpu normals", bytemuck::cast_slice(nrm), s);
            let ib = ctx.buffer_with("psao-gpu ids", bytemuck::cast_slice(sorted_ids), s);
            let (out, readback) = ctx.output_f32("psao-gpu ao out", n);
            let entries: Vec<wgpu::BindGroupEntry<'_>> = [
                (0, tlas.as_binding()),
                (1, uniform.as_entire_binding()),
                (2, pb.as_entire_binding()),
                (3, nb.as_entire_binding()),
                (4, ib.as_entire_binding()),
                (5, out.as_entire_binding()),
            ]
            .into_iter()
            .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
            .chain(scene.alpha().bind_entries())
            .collect();
            let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("psao-gpu ao bind"),
                layout: &self.layout,
                entries: &entries,
            });
            ctx.submit_pass(
                "psao-gpu ao",
                &self.pipeline,
                &[&bind],
                grid,
                &out,
                &readback,
            );
            readback
        })?;
        let mut ao = ctx.read_f32(&readback)?;
        ao.truncate(n);
        Ok(ao)
    }
}
