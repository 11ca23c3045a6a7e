//! The client's reconstruction on the GPU: `reconstruct.wgsl` (which a
//! renderer can include in its own shaders, [`RECONSTRUCT_WGSL`]) run as a
//! compute pass over a G-buffer. Needs no ray queries: compute shaders and
//! eight storage buffers per stage ([`GpuContext::client_limits`]).

use std::time::Instant;

use crate::client::gbuffer::{GBufferSlices, NO_INSTANCE};
use crate::client::mirror::GpuMirror;
use crate::context::{GpuContext, PassTimes, storage_layout, uniform_layout};
use crate::error::GpuError;

/// The reconstruction functions and their bindings (group 0, bindings
/// 0-3: instances, bucket entries, point words, normal table; see
/// [`GpuMirror::bind_entries`]). Call `psao_ao(instance, world_position,
/// world_normal)` from any shader stage; for an instance of point format 1
/// (`psao_bind_space(instance)`), pass the surface's bind-space position
/// and normal instead (spec/wire-format.md 6.1).
pub const RECONSTRUCT_WGSL: &str = include_str!("../shaders/reconstruct.wgsl");

const WORKGROUP: u32 = 64;

/// The reconstruction compute pass.
#[derive(Debug)]
pub struct GpuReconstruct {
    pipeline: wgpu::ComputePipeline,
    mirror_layout: wgpu::BindGroupLayout,
    pass_layout: wgpu::BindGroupLayout,
}

impl GpuReconstruct {
    /// Compiles the pass.
    pub fn new(ctx: &GpuContext) -> Result<GpuReconstruct, GpuError> {
        ctx.checked("reconstruction shader compilation", || {
            let source = format!(
                "{RECONSTRUCT_WGSL}\n{}",
                include_str!("../shaders/reconstruct_pass.wgsl")
            );
            let mirror_layout =
                ctx.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some("psao-gpu mirror"),
                        entries: &[
                            storage_layout(0, true),
                            storage_layout(1, true),
                            storage_layout(2, true),
                            storage_layout(3, true),
                        ],
                    });
            let pass_layout =
                ctx.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some("psao-gpu reconstruct pass"),
                        entries: &[
                            storage_layout(0, true),
                            storage_layout(1, true),
                            storage_layout(2, true),
                            storage_layout(3, false),
                            uniform_layout(4),
                        ],
                    });
            let pipeline = ctx.compute_pipeline(
                "psao-gpu reconstruct.wgsl",
                &source,
                &[&mirror_layout, &pass_layout],
            );
            GpuReconstruct {
                pipeline,
                mirror_layout,
                pass_layout,
            }
        })
    }

    /// AO per pixel of `g` from the mirror on the GPU (1 where nothing was
    /// hit or the instance cannot be sampled), read back to the host.
    /// `g` is a [`GBufferSlices`] or anything that turns into one
    /// (psao-eval's `&GBuffer`, with the feature `baseline`).
    pub fn run<'a>(
        &self,
        ctx: &GpuContext,
        mirror: &GpuMirror,
        g: impl Into<GBufferSlices<'a>>,
    ) -> Result<Vec<f32>, GpuError> {
        self.run_timed(ctx, mirror, g).map(|r| r.0)
    }

    /// [`run`](Self::run), with how long the pass and the whole call took
    /// (the mirror is already on the device).
    pub fn run_timed<'a>(
        &self,
        ctx: &GpuContext,
        mirror: &GpuMirror,
        g: impl Into<GBufferSlices<'a>>,
    ) -> Result<(Vec<f32>, PassTimes), GpuError> {
        let start = Instant::now();
        let g = g.into();
        g.check()?;
        let n = g.pixels();
        if n == 0 {
            return Ok((Vec::new(), PassTimes::default()));
        }
        let limits = ctx.device.limits();
        if (n as u64) * 16 > limits.max_storage_buffer_binding_size {
            return Err(GpuError::Limits {
                what: "G-buffer bytes",
                needed: n as u64 * 16,
                limit: limits.max_storage_buffer_binding_size,
            });
        }
        let grid = ctx.grid(n, WORKGROUP);
        // Pixels of bind-space instances are looked up by their bind-space
        // attributes (the shader's transform for them is the identity).
        // (Each pixel's instance is looked up once.)
        let bind: Vec<bool> = g.instance.iter().map(|&i| mirror.bind_space(i)).collect();
        if g.bind_position.is_empty() && bind.contains(&true) {
            return Err(GpuError::Input(
                "the mirror holds instances in bind space (point format 1): the G-buffer needs bind_position and bind_normal".into(),
            ));
        }
        let pick = |world: &[glam::Vec3], local: &[glam::Vec3]| -> Vec<[f32; 4]> {
            bind.iter()
                .enumerate()
                .map(|(k, &b)| if b { local[k] } else { world[k] }.extend(0.0).to_array())
                .collect()
        };
        let pos = pick(g.position, g.bind_position);
        let nrm = pick(g.normal, g.bind_normal);
        let ids: Vec<u32> = g
            .instance
            .iter()
            .map(|&i| if i == NO_INSTANCE { u32::MAX } else { i })
            .collect();
        let size = [n as u32, grid.0 * WORKGROUP, 0, 0];
        let (commands, out) = ctx.checked("reconstruction pass", || {
            let s = wgpu::BufferUsages::STORAGE;
            let pb = ctx.buffer_with("psao-gpu gbuffer position", bytemuck::cast_slice(&pos), s);
            let nb = ctx.buffer_with("psao-gpu gbuffer normal", bytemuck::cast_slice(&nrm), s);
            let ib = ctx.buffer_with("psao-gpu gbuffer instance", bytemuck::cast_slice(&ids), s);
            let ub = ctx.uniform("psao-gpu pass size", &size);
            let out = ctx.storage_out("psao-gpu ao image", n as u64 * 4);
            let mirror_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("psao-gpu mirror"),
                layout: &self.mirror_layout,
                entries: &mirror.bind_entries(),
            });
            let entries: Vec<wgpu::BindGroupEntry<'_>> = [&pb, &nb, &ib, &out, &ub]
                .into_iter()
                .enumerate()
                .map(|(k, b)| wgpu::BindGroupEntry {
                    binding: k as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
            let pass_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("psao-gpu reconstruct pass"),
                layout: &self.pass_layout,
                entries: &entries,
            });
            let mut enc = ctx.encoder("psao-gpu reconstruct");
            GpuContext::record_pass(
                &mut enc,
                "psao-gpu reconstruct",
                &self.pipeline,
                &[&mirror_group, &pass_group],
                grid,
            );
            (enc.finish(), out)
        })?;
        ctx.timed_passes(commands, &out, n, start)
    }
}
