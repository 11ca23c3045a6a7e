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

/// The optional hidden-candidate test of spec/wire-format.md 7.3.1, to
/// append after [`RECONSTRUCT_WGSL`]: `psao_ao_seen(instance,
/// position, normal, world_position)` is `psao_ao` leaving out the
/// candidates the view shows hidden behind another surface that faces the
/// pixel. Its bindings are group 0, bindings 4 (a uniform: the view's
/// WebGPU world-to-clip matrix and its width and height) and 5 (per pixel
/// of the view, two `vec4<u32>`: the bits of the world position with the
/// instance id in `w`, `0xFFFFFFFF` where nothing is seen, and the bits of
/// the unit world normal facing the camera). A shader that calls only
/// `psao_ao` need not append it.
pub const RECONSTRUCT_SEEN_WGSL: &str = include_str!("../shaders/reconstruct_seen.wgsl");

const WORKGROUP: u32 = 64;

/// The reconstruction compute pass.
#[derive(Debug)]
pub struct GpuReconstruct {
    /// The pass of [`RECONSTRUCT_WGSL`]: group 0 the mirror, group 1 the
    /// G-buffer and the output.
    plain: Pass,
    /// The pass with the hidden-candidate test ([`Self::run_seen`],
    /// [`RECONSTRUCT_SEEN_WGSL`]): group 0 the mirror and the view, group 1
    /// the pixels' lookup attributes and the output.
    seen: Pass,
}

/// One reconstruction compute pass: its pipeline and its two groups'
/// layouts.
#[derive(Debug)]
struct Pass {
    label: &'static str,
    pipeline: wgpu::ComputePipeline,
    mirror_layout: wgpu::BindGroupLayout,
    pass_layout: wgpu::BindGroupLayout,
}

impl Pass {
    /// Compiles `source` with group 0 of `mirror` entries and group 1 of
    /// `pass` entries.
    fn new(
        ctx: &GpuContext,
        label: &'static str,
        source: &str,
        mirror: &[wgpu::BindGroupLayoutEntry],
        pass: &[wgpu::BindGroupLayoutEntry],
    ) -> Pass {
        let layout = |entries| {
            ctx.device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(label),
                    entries,
                })
        };
        let (mirror_layout, pass_layout) = (layout(mirror), layout(pass));
        let pipeline = ctx.compute_pipeline(label, source, &[&mirror_layout, &pass_layout]);
        Pass {
            label,
            pipeline,
            mirror_layout,
            pass_layout,
        }
    }

    /// The pass over a `grid` of workgroups, recorded and finished: group
    /// 0 bound to `mirror`, group 1 to `buffers` at bindings 0, 1, ...
    fn record(
        &self,
        ctx: &GpuContext,
        mirror: &[wgpu::BindGroupEntry<'_>],
        buffers: &[&wgpu::Buffer],
        grid: (u32, u32),
    ) -> wgpu::CommandBuffer {
        let mirror_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.label),
            layout: &self.mirror_layout,
            entries: mirror,
        });
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .enumerate()
            .map(|(k, b)| wgpu::BindGroupEntry {
                binding: k as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let pass_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.label),
            layout: &self.pass_layout,
            entries: &entries,
        });
        let mut enc = ctx.encoder(self.label);
        GpuContext::record_pass(
            &mut enc,
            self.label,
            &self.pipeline,
            &[&mirror_group, &pass_group],
            grid,
        );
        enc.finish()
    }
}

impl GpuReconstruct {
    /// Compiles the pass.
    pub fn new(ctx: &GpuContext) -> Result<GpuReconstruct, GpuError> {
        ctx.checked("reconstruction shader compilation", || {
            let mirror = [
                storage_layout(0, true),
                storage_layout(1, true),
                storage_layout(2, true),
                storage_layout(3, true),
            ];
            let plain = Pass::new(
                ctx,
                "psao-gpu reconstruct",
                &format!(
                    "{RECONSTRUCT_WGSL}\n{}",
                    include_str!("../shaders/reconstruct_pass.wgsl")
                ),
                &mirror,
                &[
                    storage_layout(0, true),
                    storage_layout(1, true),
                    storage_layout(2, true),
                    storage_layout(3, false),
                    uniform_layout(4),
                ],
            );
            let seen = Pass::new(
                ctx,
                "psao-gpu reconstruct with the hidden test",
                &format!(
                    "{RECONSTRUCT_WGSL}\n{RECONSTRUCT_SEEN_WGSL}\n{}",
                    include_str!("../shaders/reconstruct_seen_pass.wgsl")
                ),
                &[&mirror[..], &[uniform_layout(4), storage_layout(5, true)]].concat(),
                &[
                    storage_layout(0, true),
                    storage_layout(1, false),
                    uniform_layout(2),
                ],
            );
            GpuReconstruct { plain, seen }
        })
    }

    /// [`run`](Self::run) with the hidden-candidate test of
    /// spec/wire-format.md 7.3.1 ([`RECONSTRUCT_SEEN_WGSL`]): `g` is what
    /// the view whose WebGPU world-to-clip matrix is `to_clip` sees, one
    /// value per pixel of a `width x height` view, row 0 at the top (as
    /// psao-eval's `View::world_to_clip` and G-buffer). The same test as
    /// psao-codec's `reconstruct_ao_seen` up to rounding: the shader
    /// rebuilds the instance's translation from its inverse's and takes
    /// the cube root with `pow`, and a candidate projected onto the edge
    /// between two pixels may land on the other one.
    pub fn run_seen<'a>(
        &self,
        ctx: &GpuContext,
        mirror: &GpuMirror,
        g: impl Into<GBufferSlices<'a>>,
        to_clip: glam::Mat4,
        width: u32,
        height: u32,
    ) -> Result<Vec<f32>, GpuError> {
        let g = g.into();
        g.check()?;
        let n = g.pixels();
        if width as u64 * height as u64 != n as u64 {
            return Err(GpuError::Input(format!(
                "a {width}x{height} view for a G-buffer of {n} pixels"
            )));
        }
        if !to_clip.is_finite() {
            return Err(GpuError::Input(
                "the view's world-to-clip matrix is not finite".into(),
            ));
        }
        if n == 0 {
            return Ok(Vec::new());
        }
        let (grid, bind) = pixel_layout(ctx, mirror, &g, 32)?;
        // (The binding limit keeps n far below this; the shader indexes
        // 2 n + 1 in u32.)
        if n as u64 >= u32::MAX as u64 / 2 {
            return Err(GpuError::Limits {
                what: "pixels",
                needed: n as u64,
                limit: u32::MAX as u64 / 2 - 1,
            });
        }
        // The view's surfaces as the shader reads them: u32 words, the
        // floats by their bits, the id as it is (NO_INSTANCE is the
        // shader's 0xFFFFFFFF).
        let bits = |v: glam::Vec3, w: u32| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits(), w];
        let mut surfaces: Vec<[u32; 4]> = Vec::with_capacity(2 * n);
        let mut lookup: Vec<[f32; 4]> = Vec::with_capacity(2 * n);
        for (k, &in_bind_space) in bind.iter().enumerate() {
            surfaces.push(bits(g.position[k], g.instance[k]));
            surfaces.push(bits(g.normal[k], 0));
            let (p, nrm) = if in_bind_space {
                (g.bind_position[k], g.bind_normal[k])
            } else {
                (g.position[k], g.normal[k])
            };
            lookup.push(p.extend(0.0).to_array());
            lookup.push(nrm.extend(0.0).to_array());
        }
        let mut view = [0u32; 20];
        for (k, v) in to_clip.to_cols_array().iter().enumerate() {
            view[k] = v.to_bits();
        }
        view[16] = width;
        view[17] = height;
        let size = [n as u32, grid.0 * WORKGROUP, 0, 0];
        let start = Instant::now();
        let (commands, out) = ctx.checked("reconstruction pass with the hidden test", || {
            let s = wgpu::BufferUsages::STORAGE;
            let sb = ctx.buffer_with("psao-gpu view surfaces", bytemuck::cast_slice(&surfaces), s);
            let lb = ctx.buffer_with("psao-gpu lookup", bytemuck::cast_slice(&lookup), s);
            let vb = ctx.uniform("psao-gpu view", &view);
            let ub = ctx.uniform("psao-gpu pass size", &size);
            let out = ctx.storage_out("psao-gpu ao image", n as u64 * 4);
            let mut mirror_entries = mirror.bind_entries().to_vec();
            mirror_entries.push(wgpu::BindGroupEntry {
                binding: 4,
                resource: vb.as_entire_binding(),
            });
            mirror_entries.push(wgpu::BindGroupEntry {
                binding: 5,
                resource: sb.as_entire_binding(),
            });
            let commands = self
                .seen
                .record(ctx, &mirror_entries, &[&lb, &out, &ub], grid);
            (commands, out)
        })?;
        ctx.timed_passes(commands, &out, n, start).map(|r| r.0)
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
        let (grid, bind) = pixel_layout(ctx, mirror, &g, 16)?;
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
            let commands = self.plain.record(
                ctx,
                &mirror.bind_entries(),
                &[&pb, &nb, &ib, &out, &ub],
                grid,
            );
            (commands, out)
        })?;
        ctx.timed_passes(commands, &out, n, start)
    }
}

/// What both passes check and need before their buffers: that the largest
/// per-pixel buffer (`bytes` a pixel) fits a storage binding, the grid of
/// workgroups, and which pixels are looked up by their bind-space
/// attributes (instances of point format 1: the shader's transform for
/// them is the identity), each pixel's instance looked up once. A mirror
/// in bind space needs the G-buffer's bind-space slices.
fn pixel_layout(
    ctx: &GpuContext,
    mirror: &GpuMirror,
    g: &GBufferSlices<'_>,
    bytes: u64,
) -> Result<((u32, u32), Vec<bool>), GpuError> {
    let n = g.pixels();
    let limits = ctx.device.limits();
    if (n as u64) * bytes > limits.max_storage_buffer_binding_size {
        return Err(GpuError::Limits {
            what: "G-buffer bytes",
            needed: n as u64 * bytes,
            limit: limits.max_storage_buffer_binding_size,
        });
    }
    let bind: Vec<bool> = g.instance.iter().map(|&i| mirror.bind_space(i)).collect();
    if g.bind_position.is_empty() && bind.contains(&true) {
        return Err(GpuError::Input(
            "the mirror holds instances in bind space (point format 1): the G-buffer needs bind_position and bind_normal".into(),
        ));
    }
    Ok((ctx.grid(n, WORKGROUP), bind))
}
