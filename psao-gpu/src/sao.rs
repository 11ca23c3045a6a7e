//! The SAO baseline on the GPU (`shaders/sao.wgsl`): psao-scene's CPU
//! passes ([`psao_eval::sao`]) as compute passes with the same constants,
//! so that the client's reconstruction ([`crate::GpuReconstruct`]) and SAO
//! can be timed on one device.

use std::time::Instant;

use psao_eval::{SaoParams, View};

use crate::context::{GpuContext, PassTimes, storage_layout, uniform_layout};
use crate::error::GpuError;

const WORKGROUP: u32 = 64;

/// Most pyramid levels the shader's level table holds (`mip_levels` is at
/// most 15, [`SaoParams::validate`]).
const LEVELS: usize = 16;

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    width: u32,
    height: u32,
    focal: f32,
    radius: f32,
    samples: u32,
    spiral_turns: f32,
    intensity: f32,
    bias: f32,
    epsilon: f32,
    contrast: f32,
    mip_levels: u32,
    log_q: u32,
    quad_max_dz: f32,
    blur_radius: u32,
    blur_stride: u32,
    blur_scale: f32,
    turn_lo: u32,
    turn_hi: u32,
    row: u32,
    horizontal: u32,
    finish: u32,
    texels: u32,
    pad: [u32; 2],
    // 16 = LEVELS, written out: rustc 1.95 breaks on a named length
    // here inside a closure's struct update.
    levels: [[u32; 4]; 16],
}

/// `10 / TAU` (the f64 TAU the CPU reduces by) as a binary fraction with
/// 64 bits, without its integer part (1): the shader reduces eq. 8's angle
/// `10 h` modulo `TAU` as `frac(h * 10 / TAU)` exactly in integers.
fn turn_fraction() -> u64 {
    let bits = std::f64::consts::TAU.to_bits();
    let mantissa = (bits & ((1 << 52) - 1)) | (1 << 52);
    let exponent = ((bits >> 52) & 0x7ff) as i32 - 1075;
    // TAU = mantissa * 2^exponent, so 10 / TAU * 2^64 =
    // 10 * 2^(64 - exponent) / mantissa.
    let shift = (64 - exponent) as u32;
    ((10u128 << shift) / mantissa as u128) as u64
}

/// Pyramid level sizes and offsets (level 0 is the image; levels 1.. are
/// stored one after another), and the texels below level 0.
fn level_table(width: u32, height: u32, levels: u32) -> ([[u32; 4]; LEVELS], u32) {
    let mut table = [[0u32; 4]; LEVELS];
    let (mut w, mut h, mut offset) = (width, height, 0u32);
    table[0] = [w, h, 0, 0];
    for level in table.iter_mut().take(levels as usize + 1).skip(1) {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        *level = [w, h, offset, 0];
        offset += w * h;
    }
    (table, offset)
}

/// SAO as compute passes.
#[derive(Debug)]
pub struct GpuSao {
    layout: wgpu::BindGroupLayout,
    pyramid: wgpu::ComputePipeline,
    obscurance: wgpu::ComputePipeline,
    quad: wgpu::ComputePipeline,
    blur: wgpu::ComputePipeline,
}

impl GpuSao {
    /// Compiles the passes.
    pub fn new(ctx: &GpuContext) -> Result<GpuSao, GpuError> {
        ctx.checked("SAO shader compilation", || {
            let layout = ctx
                .device
                .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("psao-gpu sao layout"),
                    entries: &[
                        uniform_layout(0),
                        storage_layout(1, true),
                        storage_layout(2, true),
                        storage_layout(3, true),
                        storage_layout(4, false),
                        storage_layout(5, false),
                        storage_layout(6, true),
                    ],
                });
            let source = include_str!("shaders/sao.wgsl");
            let at =
                |entry| ctx.compute_pipeline_at("psao-gpu sao.wgsl", source, entry, &[&layout]);
            GpuSao {
                pyramid: at("pyramid"),
                obscurance: at("obscurance"),
                quad: at("quad"),
                blur: at("blur"),
                layout,
            }
        })
    }

    /// SAO of a depth buffer, as [`psao_eval::sao`] (same passes, inputs,
    /// conventions and errors), on the GPU.
    pub fn run(
        &self,
        ctx: &GpuContext,
        depth: &[f32],
        view: &View,
        params: &SaoParams,
    ) -> Result<Vec<f32>, GpuError> {
        self.run_timed(ctx, depth, view, params).map(|r| r.0)
    }

    /// [`run`](Self::run), with how long the passes and the whole call
    /// took.
    pub fn run_timed(
        &self,
        ctx: &GpuContext,
        depth: &[f32],
        view: &View,
        params: &SaoParams,
    ) -> Result<(Vec<f32>, PassTimes), GpuError> {
        let start = Instant::now();
        let focal = params.check_input(depth.len(), view)?;
        let n = depth.len();
        if n == 0 {
            return Ok((Vec::new(), PassTimes::default()));
        }
        let limits = ctx.device.limits();
        let bytes = n as u64 * 4;
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::Limits {
                what: "bytes of one SAO image",
                needed: bytes,
                limit,
            });
        }
        let (levels, texels) = level_table(view.width, view.height, params.mip_levels);
        let turn = turn_fraction();
        let base = Params {
            width: view.width,
            height: view.height,
            focal,
            radius: params.radius,
            samples: params.samples,
            spiral_turns: params.spiral_turns,
            intensity: params.intensity,
            bias: params.bias,
            epsilon: params.epsilon,
            contrast: params.contrast,
            mip_levels: params.mip_levels,
            log_q: params.log_q,
            quad_max_dz: params.quad_max_dz,
            blur_radius: params.blur_radius,
            blur_stride: params.blur_stride,
            blur_scale: params.blur_edge_sharpness / params.blur_depth_range,
            turn_lo: turn as u32,
            turn_hi: (turn >> 32) as u32,
            row: 0,
            horizontal: 0,
            finish: 0,
            texels,
            pad: [0; 2],
            levels,
        };
        let gauss: Vec<f32> = (0..=params.blur_radius)
            .map(|t| (-((t * t) as f32) / (2.0 * params.blur_sigma * params.blur_sigma)).exp())
            .collect();
        let blur = params.blur_radius > 0;
        let pixel_grid = ctx.grid(n, WORKGROUP);
        let quads = (view.width.div_ceil(2) * view.height.div_ceil(2)) as usize;
        let quad_grid = ctx.grid(quads, WORKGROUP);
        let pyramid_grid = ctx.grid(texels as usize, WORKGROUP);
        let with = |grid: (u32, u32), horizontal: u32, finish: bool| Params {
            row: grid.0 * WORKGROUP,
            horizontal,
            finish: finish as u32,
            ..base
        };
        // Inputs onto the device, then the passes alone.
        let (commands, out) = ctx.checked("SAO passes", || {
            let s = wgpu::BufferUsages::STORAGE;
            let uniform = |p: Params| ctx.uniform("psao-gpu sao params", &p);
            let depth_buf = ctx.buffer_with("psao-gpu sao depth", bytemuck::cast_slice(depth), s);
            let gauss_buf = ctx.buffer_with("psao-gpu sao gauss", bytemuck::cast_slice(&gauss), s);
            let unused_in = ctx.buffer_with("psao-gpu sao unused", &[], s);
            let unused_in_u32 = ctx.buffer_with("psao-gpu sao unused", &[], s);
            let unused_out = ctx.storage_out("psao-gpu sao unused", 16);
            let pyramid = ctx.storage_out("psao-gpu sao pyramid", texels as u64 * 4);
            let image = |label| ctx.storage_out(label, bytes);
            let (raw, quad) = (image("psao-gpu sao raw"), image("psao-gpu sao quad"));
            let (across, out) = (image("psao-gpu sao blur x"), image("psao-gpu sao out"));
            let group = |p: Params,
                         pyr_in: &wgpu::Buffer,
                         src: &wgpu::Buffer,
                         dst: &wgpu::Buffer,
                         pyr_out: &wgpu::Buffer| {
                let u = uniform(p);
                ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("psao-gpu sao bind"),
                    layout: &self.layout,
                    entries: &[
                        (0, &u),
                        (1, &depth_buf),
                        (2, pyr_in),
                        (3, src),
                        (4, dst),
                        (5, pyr_out),
                        (6, &gauss_buf),
                    ]
                    .map(|(binding, b)| wgpu::BindGroupEntry {
                        binding,
                        resource: b.as_entire_binding(),
                    }),
                })
            };
            let mut enc = ctx.encoder("psao-gpu sao");
            if texels > 0 {
                let g = group(
                    with(pyramid_grid, 0, false),
                    &unused_in_u32,
                    &unused_in,
                    &unused_out,
                    &pyramid,
                );
                GpuContext::record_pass(
                    &mut enc,
                    "sao pyramid",
                    &self.pyramid,
                    &[&g],
                    pyramid_grid,
                );
            }
            let pyr_in = if texels > 0 { &pyramid } else { &unused_in_u32 };
            let g = group(
                with(pixel_grid, 0, false),
                pyr_in,
                &unused_in,
                &raw,
                &unused_out,
            );
            GpuContext::record_pass(
                &mut enc,
                "sao obscurance",
                &self.obscurance,
                &[&g],
                pixel_grid,
            );
            let g = group(
                with(quad_grid, 0, !blur),
                &unused_in_u32,
                &raw,
                &quad,
                &unused_out,
            );
            GpuContext::record_pass(&mut enc, "sao quad", &self.quad, &[&g], quad_grid);
            let last = if blur {
                let g = group(
                    with(pixel_grid, 1, false),
                    &unused_in_u32,
                    &quad,
                    &across,
                    &unused_out,
                );
                GpuContext::record_pass(&mut enc, "sao blur x", &self.blur, &[&g], pixel_grid);
                let g = group(
                    with(pixel_grid, 0, true),
                    &unused_in_u32,
                    &across,
                    &out,
                    &unused_out,
                );
                GpuContext::record_pass(&mut enc, "sao blur y", &self.blur, &[&g], pixel_grid);
                out
            } else {
                quad
            };
            (enc.finish(), last)
        })?;
        ctx.timed_passes(commands, &out, n, start)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shader's eq. 8 angle, step for step on the host.
    fn fixed_angle(x: u32, y: u32) -> f32 {
        let turn = turn_fraction();
        let h = (x.wrapping_mul(3) ^ y.wrapping_add(x.wrapping_mul(y))) as i32;
        let a = h.unsigned_abs() as u64;
        let mut v = a.wrapping_mul(turn);
        if h < 0 {
            v = v.wrapping_neg();
        }
        let hi = (v >> 32) as u32;
        let f = ((hi >> 8) as f32 + (hi & 0xFF) as f32 / 256.0) / 16_777_216.0;
        (f * std::f32::consts::TAU).min(std::f32::consts::TAU)
    }

    #[test]
    fn the_fixed_point_angle_is_the_cpu_angle() {
        // The CPU's angle: (10 h) mod TAU in f64.
        let cpu = |x: u32, y: u32| {
            let h = x.wrapping_mul(3) ^ y.wrapping_add(x.wrapping_mul(y));
            ((h as i32) as f64 * 10.0).rem_euclid(std::f64::consts::TAU) as f32
        };
        let mut worst = 0f32;
        for y in (0..16_384).step_by(97) {
            for x in (0..16_384).step_by(89) {
                let (a, b) = (fixed_angle(x, y), cpu(x, y));
                // The same direction (angles near 0 and TAU agree).
                let d = (a - b).abs().min(std::f32::consts::TAU - (a - b).abs());
                worst = worst.max(d);
            }
        }
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn level_table_matches_the_rotated_grid_sizes() {
        let (t, texels) = level_table(7, 5, 3);
        assert_eq!(t[0], [7, 5, 0, 0]);
        assert_eq!(t[1], [4, 3, 0, 0]);
        assert_eq!(t[2], [2, 2, 12, 0]);
        assert_eq!(t[3], [1, 1, 16, 0]);
        assert_eq!(texels, 17);
        assert_eq!(level_table(9, 9, 0).1, 0);
    }
}
