//! Point AO with ray queries: the compute pass of `shaders/ao.wgsl`, which
//! samples, estimates and offsets rays exactly as psao-scene's CPU tracer
//! does, so that the same seed gives the same rays on both.

use psao_scene::{AoParams, AoResult, Estimator, morton_order};
use wgpu::util::DeviceExt;

use crate::accel::GpuScene;
use crate::context::GpuContext;
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
            let module = ctx
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("psao-gpu ao.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(include_str!("shaders/ao.wgsl").into()),
                });
            let storage = |binding: u32, read_only: bool| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            };
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
                        wgpu::BindGroupLayoutEntry {
                            binding: 1,
                            visibility: wgpu::ShaderStages::COMPUTE,
                            ty: wgpu::BindingType::Buffer {
                                ty: wgpu::BufferBindingType::Uniform,
                                has_dynamic_offset: false,
                                min_binding_size: None,
                            },
                            count: None,
                        },
                        storage(2, true),
                        storage(3, true),
                        storage(4, true),
                        storage(5, false),
                        storage(6, true),
                        storage(7, true),
                    ],
                });
            let pl = ctx
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("psao-gpu ao pipeline layout"),
                    bind_group_layouts: &[Some(&layout)],
                    immediate_size: 0,
                });
            let pipeline = ctx
                .device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("psao-gpu ao"),
                    layout: Some(&pl),
                    module: &module,
                    entry_point: Some("main"),
                    compilation_options: Default::default(),
                    cache: None,
                });
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
        let limits = ctx.device.limits();
        let groups = (n as u32).div_ceil(WORKGROUP);
        let per_row = groups.min(limits.max_compute_workgroups_per_dimension.max(1));
        let rows = groups.div_ceil(per_row);
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
            row: per_row * WORKGROUP,
        };
        let readback = ctx.checked("AO pass", || {
            let d = &ctx.device;
            let init = |label, contents: &[u8], usage| {
                d.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage,
                })
            };
            let uniform = init(
                "psao-gpu ao params",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM,
            );
            let s = wgpu::BufferUsages::STORAGE;
            let pb = init("psao-gpu points", bytemuck::cast_slice(pts), s);
            let nb = init("psao-gpu normals", bytemuck::cast_slice(nrm), s);
            let ib = init("psao-gpu ids", bytemuck::cast_slice(sorted_ids), s);
            let size = (n * 4) as u64;
            let out = d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("psao-gpu ao out"),
                size,
                usage: s | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let readback = d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("psao-gpu ao readback"),
                size,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let bind = d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("psao-gpu ao bind"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: tlas.as_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: pb.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: nb.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: ib.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: out.as_entire_binding(),
                    },
                ]
                .into_iter()
                .chain(scene.alpha().bind_entries())
                .collect::<Vec<_>>(),
            });
            let mut enc = d.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("psao-gpu ao"),
            });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("psao-gpu ao"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(per_row, rows, 1);
            }
            enc.copy_buffer_to_buffer(&out, 0, &readback, 0, size);
            ctx.queue.submit(Some(enc.finish()));
            readback
        })?;
        ctx.read_f32(&readback)
    }
}
