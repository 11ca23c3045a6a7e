//! Scalable Ambient Obscurance (McGuire, Mara and Luebke, HPG 2012, the
//! authors' revised version of 2012-12-03), on the CPU: the screen-space
//! baseline the ray-traced AO is compared with.
//!
//! [`sao`] takes a depth buffer in the [`View`] convention (distance along
//! the view axis, row `py = 0` at the top) and returns the ambient
//! visibility of every pixel, 1 = fully open (the convention of our
//! ray-traced AO). The passes follow the paper:
//!
//! 1. camera-space z (section 2.2): our depth already is `-z`, so eq. 2 is
//!    not needed; values that are not finite or not positive are sky;
//! 2. the z MIP pyramid by rotated-grid subsampling (section 2.2, table 1),
//!    `levels` below full resolution;
//! 3. the distributed AO sample pass (section 2.3): position from depth
//!    (eq. 3), face normal from screen-space derivatives (eq. 4), the
//!    screen-space radius (eq. 5), `s` taps on a spiral (eqs. 6-7) turned
//!    per pixel by AlchemyAO's XOR hash (eq. 8), each read from the MIP
//!    level its distance selects (eqs. 9-10), scored by the AlchemyAO
//!    estimator (eq. 1), then the 2 x 2 bilateral box filter over a quad;
//! 4. two bilateral 1D passes, horizontal then vertical (section 2.4).
//!
//! Where this differs from the GPU version, and why:
//! - a tap reads, from level `m`, the full-resolution pixel the rotated
//!   grid picked for that texel, and its point is reconstructed at that
//!   pixel (the GPU shader reconstructs it at the tap's pixel centre with
//!   the texel's z, so on a sloped surface the point leaves the surface by
//!   up to `2^m - 1` pixels of slope). Table 1 motivates the rotated grid
//!   by "true scene values, no bias"; carrying the source pixel keeps the
//!   points true scene points too. On a surface facing the camera both
//!   give the same point;
//! - there is no guard band (section 4): taps that leave the image count
//!   as unoccluded;
//! - the blur compares float depths, not the 16-bit key packed into RGB8
//!   (section 2.3), and skips sky pixels instead of relying on a depth
//!   test;
//! - the work is split by rows with rayon; every pixel's value depends only
//!   on the input, so the result does not depend on the thread count.

use std::f32::consts::TAU;

use glam::Vec3;
use rayon::prelude::*;

use crate::view::View;
use psao_scene::{SceneError, check_param};

/// Constants of SAO. [`Default`] gives the paper's values where it has
/// them and documented choices where it leaves them open.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SaoParams {
    /// World-space sample radius `r`, metres (eq. 5). Default 0.6, the AO
    /// radius R of our ray-traced AO, so the two are compared at the same
    /// scale.
    pub radius: f32,
    /// Taps per pixel `s` (eq. 1, eq. 6). Default 9, the paper's `s = 9`
    /// (section 2.3, figure 5).
    pub samples: u32,
    /// Spiral turns `tau` (eq. 6). Default 7, the paper's value for
    /// `s = 9` (section 2.3).
    pub spiral_turns: f32,
    /// Intensity `sigma` of eq. 1, metres (the sum of eq. 1 has units of
    /// 1 / length). The paper chooses it "for aesthetics" and gives no
    /// value. Default 0.25, calibrated for a fair comparison with our
    /// ray-traced AO: the value that best fits (least squares over the
    /// distance profile) cosine-weighted closest-hit AO with R = 0.6 on
    /// two 90 degree inside corners at 192 x 144, fov 60 degrees: a
    /// floor-wall corner 4 m away seen from 1 m above the floor (RMSE
    /// 0.07) and a vertical corner seen at 45 degrees (RMSE 0.03). Larger
    /// values saturate creases to black, smaller ones wash them out. It
    /// scales with the radius: keep `intensity / radius` constant when
    /// changing `radius` to keep the same look.
    pub intensity: f32,
    /// Bias `beta` of eq. 1 (dimensionless: the term is `z_C * beta`, a
    /// bias distance growing with depth). The paper gives no value.
    /// Default 1e-4: 0.1 mm per metre of depth, far above the f32 error of
    /// reconstructed positions (about 1e-7 of the depth) so flat surfaces
    /// do not occlude themselves, far below the radius so contact
    /// occlusion stays.
    pub bias: f32,
    /// `epsilon` of eq. 1, square metres (it is added to `v . v`). Default
    /// 0.01, the appendix's "epsilon ~ 1 cm in human-scale scenes" as the
    /// authors' code applies it (0.01 added to `v . v`): a larger value
    /// than the minimum against division by zero, which keeps taps very
    /// close to the centre from over-darkening creases.
    pub epsilon: f32,
    /// Contrast exponent `k` of eq. 1. The paper gives no value. Default
    /// 1: the plain estimator, no aesthetic contrast boost.
    pub contrast: f32,
    /// MIP levels of the z pyramid below full resolution (the GLSL
    /// excerpt's `MAX_MIP`, section 2.3). Default 5.
    pub mip_levels: u32,
    /// `log2 q'` (eq. 9): the level of a tap at screen distance `h` is
    /// `floor(log2 h) - log_q`, clamped to `0..=mip_levels`. The paper
    /// found `2^3 <= q' <= 2^5` equivalent; default 3 (`q' = 8`), the
    /// finest-level choice of that range, since a CPU pays little for the
    /// cache misses the larger values avoid on a GPU.
    pub log_q: u32,
    /// The 2 x 2 quad filter at the end of the AO pass (section 2.3)
    /// averages two neighbours of a quad only when their depths differ by
    /// less than this, metres. The paper only says "no significant depth
    /// discontinuity"; default 0.02 m, the threshold of the authors' G3D
    /// shader (`abs(dFdx(C.z)) < 0.02`). 0 disables the quad filter.
    pub quad_max_dz: f32,
    /// Taps on each side of the centre in each bilateral pass (section
    /// 2.4). Default 3: the paper's seven taps. 0 disables the blur.
    pub blur_radius: u32,
    /// Pixels between bilateral taps (section 2.4). Default 3, the paper's
    /// stride, possible because the quad filter already averaged 2 x 2.
    pub blur_stride: u32,
    /// Standard deviation of the Gaussian blur weights, in taps. The paper
    /// says "Gaussian weights" and gives no width. Default 2: the outer
    /// taps (at 3) keep a third of the centre weight, a wide filter that
    /// is still peaked at the centre.
    pub blur_sigma: f32,
    /// Edge sharpness of the bilateral weight: a tap's Gaussian weight is
    /// multiplied by `max(0, 1 - sharpness * |dz| / blur_depth_range)`.
    /// Default 2^11, the paper's constant (section 2.4).
    pub blur_edge_sharpness: f32,
    /// Depth range the linear depth difference is divided by, metres: the
    /// paper's `|z_min|`, 200 m for its results (section 2.3). With the
    /// defaults a tap's weight drops to 0 at a depth difference of
    /// 200 / 2048, about 10 cm.
    pub blur_depth_range: f32,
}

impl Default for SaoParams {
    fn default() -> Self {
        SaoParams {
            radius: 0.6,
            samples: 9,
            spiral_turns: 7.0,
            intensity: 0.25,
            bias: 1e-4,
            epsilon: 0.01,
            contrast: 1.0,
            mip_levels: 5,
            log_q: 3,
            quad_max_dz: 0.02,
            blur_radius: 3,
            blur_stride: 3,
            blur_sigma: 2.0,
            blur_edge_sharpness: 2048.0,
            blur_depth_range: 200.0,
        }
    }
}

/// Most taps per pixel accepted.
const MAX_SAMPLES: u32 = 1024;

impl SaoParams {
    /// Checks every constant is finite and in range: radius in
    /// `(0, 1e30]`, samples in `1..=1024`, spiral turns in `[0, 1024]`,
    /// intensity in `[0, 1e6]`, bias in `[0, 1]`, epsilon in `(0, 1e6]`,
    /// contrast in `[1e-3, 100]`, MIP levels and `log_q` in `0..=15`,
    /// quad threshold in `[0, 1e30]`, blur radius in `0..=64` taps, blur
    /// stride in `1..=64` pixels, blur sigma in `[1e-3, 1e3]`, edge
    /// sharpness in `[0, 1e30]` and depth range in `(0, 1e30]`.
    /// Errors are [`SceneError::Parameter`].
    pub fn validate(&self) -> Result<(), SceneError> {
        check_param(
            "radius",
            self.radius as f64,
            1e-30,
            1e30,
            "finite and positive",
        )?;
        check_param(
            "samples",
            self.samples as f64,
            1.0,
            MAX_SAMPLES as f64,
            "1 to 1024",
        )?;
        check_param(
            "spiral_turns",
            self.spiral_turns as f64,
            0.0,
            1024.0,
            "finite, 0 to 1024",
        )?;
        check_param(
            "intensity",
            self.intensity as f64,
            0.0,
            1e6,
            "finite, 0 to 1e6",
        )?;
        check_param("bias", self.bias as f64, 0.0, 1.0, "finite, 0 to 1")?;
        check_param(
            "epsilon",
            self.epsilon as f64,
            1e-30,
            1e6,
            "finite, positive, at most 1e6",
        )?;
        check_param(
            "contrast",
            self.contrast as f64,
            1e-3,
            100.0,
            "finite, 1e-3 to 100",
        )?;
        check_param("mip_levels", self.mip_levels as f64, 0.0, 15.0, "0 to 15")?;
        check_param("log_q", self.log_q as f64, 0.0, 15.0, "0 to 15")?;
        check_param(
            "quad_max_dz",
            self.quad_max_dz as f64,
            0.0,
            1e30,
            "finite and not negative",
        )?;
        check_param(
            "blur_radius",
            self.blur_radius as f64,
            0.0,
            64.0,
            "0 to 64 taps",
        )?;
        check_param(
            "blur_stride",
            self.blur_stride as f64,
            1.0,
            64.0,
            "1 to 64 pixels",
        )?;
        check_param(
            "blur_sigma",
            self.blur_sigma as f64,
            1e-3,
            1e3,
            "finite, 1e-3 to 1e3 taps",
        )?;
        check_param(
            "blur_edge_sharpness",
            self.blur_edge_sharpness as f64,
            0.0,
            1e30,
            "finite and not negative",
        )?;
        check_param(
            "blur_depth_range",
            self.blur_depth_range as f64,
            1e-30,
            1e30,
            "finite and positive",
        )
    }
}

impl SaoParams {
    /// Checks these constants and a depth buffer of `depth_len` values for
    /// `view`, as [`sao`] does (its errors), and returns the focal length
    /// in pixels. For other implementations of the same passes (psao-gpu's).
    pub fn check_input(&self, depth_len: usize, view: &View) -> Result<f32, SceneError> {
        self.validate()?;
        if depth_len != view.pixels() {
            return Err(SceneError::Parameter {
                name: "depth length",
                value: depth_len as f64,
                rule: "must equal width * height of the view",
            });
        }
        let focal = view.focal_px();
        check_param(
            "focal length",
            focal as f64,
            1e-30,
            f32::MAX as f64,
            "finite and positive (field of view in (0, pi))",
        )?;
        Ok(focal)
    }
}

/// One level of the z pyramid: for each texel, the full-resolution pixel
/// the rotated grid picked (its camera-space z is that pixel's).
struct Level {
    width: usize,
    height: usize,
    /// Index of the full-resolution source pixel of each texel.
    src: Vec<usize>,
}

/// The z MIP pyramid, level 0 at full resolution and `levels` below it,
/// by the rotated-grid subsample of table 1:
/// `z^{m+1}(x, y) = z^m(2x + ((y & 1) ^ 1), 2y + ((x & 1) ^ 1))`.
/// Level sizes round up (`ceil(w / 2)`), and a source coordinate past the
/// edge of an odd-sized level is clamped to it, so every full-resolution
/// tap `p` has a texel `p >> m` on every level.
fn build_pyramid(width: usize, height: usize, levels: u32) -> Vec<Level> {
    let mut pyramid = vec![Level {
        width,
        height,
        src: (0..width * height).collect(),
    }];
    for _ in 0..levels {
        let prev = &pyramid[pyramid.len() - 1];
        let (w, h) = (prev.width.div_ceil(2), prev.height.div_ceil(2));
        let mut src = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let sx = (2 * x + ((y & 1) ^ 1)).min(prev.width - 1);
                let sy = (2 * y + ((x & 1) ^ 1)).min(prev.height - 1);
                src.push(prev.src[sy * prev.width + sx]);
            }
        }
        pyramid.push(Level {
            width: w,
            height: h,
            src,
        });
    }
    pyramid
}

/// The per-pixel rotation angle `phi` of eq. 8, AlchemyAO's XOR hash, as
/// the authors' shader evaluates it with C operator precedence:
/// `10 * ((3x) ^ (y + x y))` radians (integer arithmetic wrapping as on the
/// GPU), reduced to `[0, 2 pi)`.
fn rotation_angle(x: usize, y: usize) -> f32 {
    let (x, y) = (x as u32, y as u32);
    let hash = x.wrapping_mul(3) ^ y.wrapping_add(x.wrapping_mul(y));
    ((hash as i32) as f64 * 10.0).rem_euclid(std::f64::consts::TAU) as f32
}

/// MIP level of a tap at screen distance `h` pixels (eq. 9, as the
/// paper's GLSL excerpt: `clamp(findMSB(int(h)) - log_q, 0, MAX_MIP)`).
fn mip_level(h: f32, log_q: u32, levels: u32) -> usize {
    if h < 1.0 {
        return 0;
    }
    let msb = (h as u64).ilog2();
    msb.saturating_sub(log_q).min(levels) as usize
}

/// The input resampled into what the passes need: camera-space points and
/// depths (sky = infinite depth) of every pixel.
struct Frame {
    width: usize,
    height: usize,
    /// Depth of each pixel, `f32::INFINITY` for sky.
    z: Vec<f32>,
    /// View-space point of each pixel (unused for sky).
    pos: Vec<Vec3>,
}

impl Frame {
    fn new(depth: &[f32], view: &View) -> Frame {
        let (width, height) = (view.width as usize, view.height as usize);
        let mut z = vec![f32::INFINITY; depth.len()];
        let mut pos = vec![Vec3::ZERO; depth.len()];
        for (i, (&d, (zi, pi))) in depth.iter().zip(z.iter_mut().zip(&mut pos)).enumerate() {
            if d.is_finite() && d > 0.0 {
                // Eq. 3: the point of pixel (x, y) at depth d.
                let p = view.view_point((i % width) as u32, (i / width) as u32, d);
                if p.is_finite() {
                    *zi = d;
                    *pi = p;
                }
            }
        }
        Frame {
            width,
            height,
            z,
            pos,
        }
    }

    fn valid(&self, i: usize) -> bool {
        self.z[i].is_finite()
    }

    /// One screen-space derivative of the position at pixel `i`: of the
    /// two one-sided differences (`next - C` and `C - prev`, both along
    /// the increasing pixel coordinate), the one whose neighbour is
    /// closer in depth, so the derivative does not straddle a depth edge
    /// when one side is continuous.
    fn derivative(&self, i: usize, prev: Option<usize>, next: Option<usize>) -> Option<Vec3> {
        let c = self.pos[i];
        let d = self.z[i];
        let fwd = next
            .filter(|&j| self.valid(j))
            .map(|j| (self.pos[j] - c, (self.z[j] - d).abs()));
        let back = prev
            .filter(|&j| self.valid(j))
            .map(|j| (c - self.pos[j], (self.z[j] - d).abs()));
        match (fwd, back) {
            (Some(f), Some(b)) => Some(if b.1 < f.1 { b.0 } else { f.0 }),
            (Some(f), None) => Some(f.0),
            (None, Some(b)) => Some(b.0),
            (None, None) => None,
        }
    }

    /// Face normal of valid pixel `(x, y)` from the screen-space
    /// derivatives of the reconstructed positions (eq. 4):
    /// `normalize(dC/dy' x dC/dx')`. With rows counted downwards this
    /// order gives the normal that faces the camera; it is flipped to face
    /// it if it does not. Where a derivative cannot be formed (no valid
    /// neighbour, a one-pixel image, overflow) the normal points back at
    /// the camera.
    fn normal(&self, x: usize, y: usize) -> Vec3 {
        let (w, h) = (self.width, self.height);
        let i = y * w + x;
        let c = self.pos[i];
        let fallback = (-c).normalize_or(Vec3::Z);
        let dx = self.derivative(
            i,
            x.checked_sub(1).map(|_| i - 1),
            (x + 1 < w).then_some(i + 1),
        );
        let dy = self.derivative(
            i,
            y.checked_sub(1).map(|_| i - w),
            (y + 1 < h).then_some(i + w),
        );
        let (Some(dx), Some(dy)) = (dx, dy) else {
            return fallback;
        };
        let n = dy.cross(dx).normalize_or(fallback);
        if n.dot(c) > 0.0 { -n } else { n }
    }
}

/// The raw obscurance estimate of valid pixel `(x, y)` (section 2.3).
fn ao_at(frame: &Frame, pyramid: &[Level], p: &SaoParams, focal: f32, x: usize, y: usize) -> f32 {
    let i = y * frame.width + x;
    let c = frame.pos[i];
    let n = frame.normal(x, y);
    // Eq. 5: r' = -r S' / z_C, S' = focal length in pixels, -z_C = depth.
    let r_px = p.radius * focal / frame.z[i];
    let phi = rotation_angle(x, y);
    let r2 = p.radius * p.radius;
    let s = p.samples as f32;
    let mut sum = 0.0f32;
    for k in 0..p.samples {
        // Eq. 6-7: the spiral tap.
        let alpha = (k as f32 + 0.5) / s;
        let h = r_px * alpha;
        let theta = TAU * alpha * p.spiral_turns + phi;
        let tx = x as f32 + 0.5 + h * theta.cos();
        let ty = y as f32 + 0.5 + h * theta.sin();
        if !(tx >= 0.0 && ty >= 0.0 && tx < frame.width as f32 && ty < frame.height as f32) {
            // Off the image (no guard band), or not finite.
            continue;
        }
        let (tx, ty) = (tx as usize, ty as usize);
        // Eq. 9-10: the level by the tap distance, the texel `tap >> m`.
        let m = mip_level(h, p.log_q, p.mip_levels);
        let level = &pyramid[m];
        let texel = (ty >> m).min(level.height - 1) * level.width + (tx >> m).min(level.width - 1);
        let j = level.src[texel];
        if !frame.valid(j) {
            continue;
        }
        // Eq. 1 on the ball of radius r about C.
        let v = frame.pos[j] - c;
        let vv = v.dot(v);
        if !(vv.is_finite() && vv < r2) {
            continue;
        }
        let num = (v.dot(n) + c.z * p.bias).max(0.0);
        let term = num / (vv + p.epsilon);
        if term.is_finite() {
            sum += term;
        }
    }
    (1.0 - 2.0 * p.intensity / s * sum)
        .max(0.0)
        .powf(p.contrast)
}

/// The 2 x 2 bilateral box filter at the end of the AO pass (section 2.3):
/// within each quad (even-aligned), horizontal neighbours are averaged,
/// then vertical ones, where both are geometry and their depths differ by
/// less than `max_dz` (the GPU's `A -= dFdx(A) * ((x & 1) - 0.5)`).
fn quad_filter(ao: &mut [f32], frame: &Frame, max_dz: f32) {
    let (w, z) = (frame.width, &frame.z);
    let close = |a: usize, b: usize| (z[a] - z[b]).abs() < max_dz;
    ao.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for x in (0..w.saturating_sub(1)).step_by(2) {
            let (a, b) = (y * w + x, y * w + x + 1);
            if close(a, b) {
                let mean = 0.5 * (row[x] + row[x + 1]);
                row[x] = mean;
                row[x + 1] = mean;
            }
        }
    });
    ao.par_chunks_mut(2 * w).enumerate().for_each(|(qy, rows)| {
        if rows.len() < 2 * w {
            return;
        }
        for x in 0..w {
            let (a, b) = (2 * qy * w + x, (2 * qy + 1) * w + x);
            if close(a, b) {
                let mean = 0.5 * (rows[x] + rows[w + x]);
                rows[x] = mean;
                rows[w + x] = mean;
            }
        }
    });
}

/// One bilateral 1D pass (section 2.4): `2 * blur_radius + 1` taps
/// `blur_stride` pixels apart along the axis, Gaussian weights times
/// `max(0, 1 - sharpness * |dz| / range)`; sky taps and taps off the
/// image are left out.
fn blur_pass(src: &[f32], frame: &Frame, p: &SaoParams, horizontal: bool) -> Vec<f32> {
    let (w, h) = (frame.width, frame.height);
    let z = &frame.z;
    let taps = p.blur_radius as usize;
    let stride = p.blur_stride as usize;
    let gauss: Vec<f32> = (0..=taps)
        .map(|t| (-((t * t) as f32) / (2.0 * p.blur_sigma * p.blur_sigma)).exp())
        .collect();
    let scale = p.blur_edge_sharpness / p.blur_depth_range;
    let mut out = vec![1.0f32; src.len()];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            if !frame.valid(i) {
                continue;
            }
            let mut sum = gauss[0] * src[i];
            let mut total = gauss[0];
            for (t, &g) in gauss.iter().enumerate().skip(1) {
                let off = t * stride;
                let (before, after) = if horizontal {
                    (
                        x.checked_sub(off).map(|nx| y * w + nx),
                        (x + off < w).then(|| i + off),
                    )
                } else {
                    (
                        y.checked_sub(off).map(|ny| ny * w + x),
                        (y + off < h).then(|| i + off * w),
                    )
                };
                for j in [before, after].into_iter().flatten() {
                    if !frame.valid(j) {
                        continue;
                    }
                    let weight = g * (1.0 - scale * (z[j] - z[i]).abs()).max(0.0);
                    if weight > 0.0 {
                        sum += weight * src[j];
                        total += weight;
                    }
                }
            }
            *o = sum / total;
        }
    });
    out
}

/// Scalable Ambient Obscurance of a depth buffer: the ambient visibility
/// of every pixel in `[0, 1]` (1 = open, 0 = fully obscured), row-major
/// like `depth`. `depth` holds, per pixel, the distance along the view
/// axis in the [`View`] convention; a value that is not finite or not
/// positive (or whose point overflows) is sky / no geometry, which gets
/// 1.0 and occludes nothing. See the module docs for the passes and
/// [`SaoParams`] for the constants.
///
/// Errors: [`SceneError::Parameter`] for a parameter out of range (see
/// [`SaoParams::validate`]), for `depth.len() != view.pixels()` (name
/// `depth length`) and for a view whose focal length is not finite and
/// positive (name `focal length`).
pub fn sao(depth: &[f32], view: &View, params: &SaoParams) -> Result<Vec<f32>, SceneError> {
    let focal = params.check_input(depth.len(), view)?;
    if depth.is_empty() {
        return Ok(Vec::new());
    }
    let frame = Frame::new(depth, view);
    let pyramid = build_pyramid(frame.width, frame.height, params.mip_levels);

    let mut ao = vec![1.0f32; depth.len()];
    ao.par_chunks_mut(frame.width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, a) in row.iter_mut().enumerate() {
                if frame.valid(y * frame.width + x) {
                    *a = ao_at(&frame, &pyramid, params, focal, x, y);
                }
            }
        });
    quad_filter(&mut ao, &frame, params.quad_max_dz);
    if params.blur_radius > 0 {
        ao = blur_pass(&ao, &frame, params, true);
        ao = blur_pass(&ao, &frame, params, false);
    }
    for (i, a) in ao.iter_mut().enumerate() {
        *a = if frame.valid(i) && a.is_finite() {
            a.clamp(0.0, 1.0)
        } else {
            1.0
        };
    }
    Ok(ao)
}

#[cfg(test)]
mod tests {
    use super::*;
    use psao_scene::Camera;

    fn view(width: u32, height: u32) -> View {
        View::new(
            Camera {
                eye: Vec3::new(0.0, 1.0, 5.0),
                target: Vec3::ZERO,
                fov_y: 60f32.to_radians(),
            },
            width,
            height,
        )
        .unwrap()
    }

    /// Depth of the nearest of view-space planes `(n, d)` (points with
    /// `n . p = d`, visible side towards the camera) per pixel, by ray-plane
    /// intersection along `view_dir` (whose z is -1, so the ray parameter is
    /// the depth). Missed pixels get infinity.
    fn planes_depth(view: &View, planes: &[(Vec3, f32)]) -> Vec<f32> {
        let mut depth = Vec::with_capacity(view.pixels());
        for py in 0..view.height {
            for px in 0..view.width {
                let dir = view.view_dir(px, py);
                let t = planes
                    .iter()
                    .filter_map(|&(n, d)| {
                        let dn = dir.dot(n);
                        (dn.abs() > 1e-9).then(|| d / dn).filter(|&t| t > 0.0)
                    })
                    .fold(f32::INFINITY, f32::min);
                depth.push(t);
            }
        }
        depth
    }

    /// A floor at y = -1 and a back wall at z = -4: an inside corner whose
    /// crease runs across the image.
    fn corner(view: &View) -> Vec<f32> {
        planes_depth(view, &[(Vec3::Y, -1.0), (Vec3::Z, -4.0)])
    }

    #[test]
    fn defaults_are_valid_and_checked() {
        assert!(SaoParams::default().validate().is_ok());
        let bad = [
            SaoParams {
                radius: 0.0,
                ..Default::default()
            },
            SaoParams {
                radius: -1.0,
                ..Default::default()
            },
            SaoParams {
                radius: f32::NAN,
                ..Default::default()
            },
            SaoParams {
                samples: 0,
                ..Default::default()
            },
            SaoParams {
                samples: 1025,
                ..Default::default()
            },
            SaoParams {
                intensity: f32::INFINITY,
                ..Default::default()
            },
            SaoParams {
                epsilon: 0.0,
                ..Default::default()
            },
            SaoParams {
                bias: -0.1,
                ..Default::default()
            },
            SaoParams {
                contrast: 0.0,
                ..Default::default()
            },
            SaoParams {
                mip_levels: 16,
                ..Default::default()
            },
            SaoParams {
                blur_stride: 0,
                ..Default::default()
            },
            SaoParams {
                blur_sigma: f32::NAN,
                ..Default::default()
            },
            SaoParams {
                blur_depth_range: 0.0,
                ..Default::default()
            },
        ];
        for p in bad {
            assert!(
                matches!(p.validate(), Err(SceneError::Parameter { .. })),
                "{p:?}"
            );
            assert!(sao(&[1.0; 4], &view(2, 2), &p).is_err());
        }
    }

    #[test]
    fn mismatched_length_is_an_error() {
        let v = view(8, 6);
        match sao(&[1.0; 47], &v, &SaoParams::default()) {
            Err(SceneError::Parameter { name, value, .. }) => {
                assert_eq!(name, "depth length");
                assert_eq!(value, 47.0);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn pyramid_is_a_rotated_grid_subsample() {
        let pyramid = build_pyramid(7, 5, 3);
        assert_eq!(pyramid.len(), 4);
        assert_eq!((pyramid[1].width, pyramid[1].height), (4, 3));
        assert_eq!((pyramid[3].width, pyramid[3].height), (1, 1));
        // Level 1 texel (x, y) = level 0 pixel (2x + (y&1 ^ 1), 2y + (x&1 ^ 1)).
        assert_eq!(pyramid[1].src[0], 7 + 1); // (0,0) <- (1,1)
        assert_eq!(pyramid[1].src[1], 3); // (1,0) <- (3,0)
        // (0,1): sx = 0 + 0 = 0, sy = 2 + 1 = 3 -> 3 * 7 + 0.
        assert_eq!(pyramid[1].src[4], 21);
        // (3,0): sx = 6 + 1 = 7 -> clamped to 6, sy = 0 + 0 = 0.
        assert_eq!(pyramid[1].src[3], 6);
        // Every texel of every level is some real pixel (no averaging).
        for level in &pyramid {
            assert!(level.src.iter().all(|&s| s < 35));
        }
    }

    #[test]
    fn mip_level_follows_tap_distance() {
        assert_eq!(mip_level(0.3, 3, 5), 0);
        assert_eq!(mip_level(15.9, 3, 5), 0);
        assert_eq!(mip_level(16.0, 3, 5), 1);
        assert_eq!(mip_level(40.0, 3, 5), 2);
        assert_eq!(mip_level(1e6, 3, 5), 5);
        assert_eq!(mip_level(1e30, 3, 2), 2);
    }

    #[test]
    fn rotation_angle_is_the_alchemy_hash() {
        // 10 * ((3 * 2) ^ (5 + 10)) = 10 * (6 ^ 15) = 90 radians.
        let expected = 90f64.rem_euclid(std::f64::consts::TAU) as f32;
        assert!((rotation_angle(2, 5) - expected).abs() < 1e-6);
        assert_eq!(rotation_angle(0, 0), 0.0);
        let big = rotation_angle(16_383, 16_383);
        assert!((0.0..TAU).contains(&big));
    }

    #[test]
    fn flat_plane_facing_the_camera_is_open() {
        let v = view(64, 48);
        let ao = sao(&vec![3.0; v.pixels()], &v, &SaoParams::default()).unwrap();
        assert!(
            ao.iter().all(|&a| a > 0.999),
            "{:?}",
            ao.iter().copied().fold(1.0, f32::min)
        );
    }

    #[test]
    fn sloped_floor_is_open() {
        // The floor alone (sky above the horizon): no self-occlusion even
        // with taps read from coarse MIP levels.
        let v = view(80, 60);
        let depth = planes_depth(&v, &[(Vec3::Y, -1.0)]);
        assert!(depth.iter().any(|d| d.is_infinite()));
        let params = SaoParams {
            radius: 2.0,
            ..Default::default()
        };
        let ao = sao(&depth, &v, &params).unwrap();
        let min = ao.iter().copied().fold(1.0, f32::min);
        assert!(min > 0.99, "{min}");
    }

    /// Mean AO of row `y`, 8 pixels in from the sides.
    fn row_mean(ao: &[f32], w: usize, y: usize) -> f32 {
        ao[y * w + 8..y * w + w - 8].iter().sum::<f32>() / (w - 16) as f32
    }

    #[test]
    fn inside_corner_is_darker_at_the_crease() {
        let v = view(96, 72);
        let depth = corner(&v);
        let ao = sao(&depth, &v, &SaoParams::default()).unwrap();
        let w = v.width as usize;
        // The first floor row (the crease is between it and the row above).
        let crease = (0..v.height as usize)
            .find(|&y| depth[y * w + w / 2] < 4.0)
            .unwrap();
        let near = 0.5 * (row_mean(&ao, w, crease - 1) + row_mean(&ao, w, crease));
        let far_wall = row_mean(&ao, w, 2);
        let far_floor = row_mean(&ao, w, v.height as usize - 2);
        assert!(far_wall > 0.99, "{far_wall}");
        assert!(far_floor > 0.99, "{far_floor}");
        assert!(near < far_wall - 0.1, "near {near} far {far_wall}");
        // Up the wall, AO rises away from the crease (in bands of two
        // rows, against the sampling noise).
        let bands: Vec<f32> = (0..4)
            .map(|k| {
                0.5 * (row_mean(&ao, w, crease - 1 - 4 * k) + row_mean(&ao, w, crease - 3 - 4 * k))
            })
            .collect();
        assert!(bands.windows(2).all(|p| p[1] > p[0]), "{bands:?}");
        assert!(bands[3] > bands[0] + 0.05, "{bands:?}");
    }

    #[test]
    fn vertical_corner_matches_the_calibration() {
        // Two walls meeting at a vertical crease 4 m ahead, each at 45
        // degrees to the view: SAO is about half open at the crease (the
        // cosine-weighted visibility there is 0.5) and open beyond R.
        let v = view(96, 72);
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let (n1, n2) = (Vec3::new(s, 0.0, s), Vec3::new(-s, 0.0, s));
        let c = Vec3::new(0.0, 0.0, -4.0);
        let depth = planes_depth(&v, &[(n1, n1.dot(c)), (n2, n2.dot(c))]);
        let ao = sao(&depth, &v, &SaoParams::default()).unwrap();
        let w = v.width as usize;
        let column = |x: usize| (20..52).map(|y| ao[y * w + x]).sum::<f32>() / 32.0;
        let crease = 0.5 * (column(w / 2 - 1) + column(w / 2));
        assert!((0.4..0.7).contains(&crease), "{crease}");
        assert!(column(3) > 0.99 && column(w - 4) > 0.99);
        assert!(column(w / 2 - 6) > crease + 0.1);
    }

    #[test]
    fn sky_pixels_are_one() {
        let v = view(40, 30);
        let mut depth = corner(&v);
        for (i, d) in depth.iter_mut().enumerate() {
            if i % 7 == 0 {
                *d = f32::INFINITY;
            } else if i % 11 == 0 {
                *d = f32::NAN;
            } else if i % 13 == 0 {
                *d = -2.0;
            } else if i % 17 == 0 {
                *d = 0.0;
            }
        }
        let ao = sao(&depth, &v, &SaoParams::default()).unwrap();
        for (i, (&d, &a)) in depth.iter().zip(&ao).enumerate() {
            if !(d.is_finite() && d > 0.0) {
                assert_eq!(a, 1.0, "pixel {i}");
            }
        }
        let all_sky = sao(&vec![f32::INFINITY; v.pixels()], &v, &SaoParams::default()).unwrap();
        assert!(all_sky.iter().all(|&a| a == 1.0));
    }

    #[test]
    fn noise_gives_finite_values_in_range() {
        let v = view(50, 37);
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -1.0,
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-40,
        ];
        let depth: Vec<f32> = (0..v.pixels())
            .map(|_| {
                s = s
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (s >> 33) as u32;
                if u.is_multiple_of(5) {
                    specials[(u / 5) as usize % specials.len()]
                } else {
                    0.1 + (u % 10_000) as f32 * 1e-3
                }
            })
            .collect();
        for params in [
            SaoParams::default(),
            SaoParams {
                radius: 1e29,
                intensity: 1e6,
                epsilon: 1e-30,
                contrast: 100.0,
                ..Default::default()
            },
        ] {
            let ao = sao(&depth, &v, &params).unwrap();
            assert_eq!(ao.len(), depth.len());
            assert!(ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
        }
        // Tiny images.
        for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 2)] {
            let v = view(w, h);
            let ao = sao(&vec![2.0; v.pixels()], &v, &SaoParams::default()).unwrap();
            assert!(ao.iter().all(|a| a.is_finite() && (0.0..=1.0).contains(a)));
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let v = view(70, 50);
        let depth = corner(&v);
        let params = SaoParams::default();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| sao(&depth, &v, &params).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_eq!(one, sao(&depth, &v, &params).unwrap());
    }

    #[test]
    fn blur_reduces_noise_but_keeps_depth_edges() {
        let v = view(96, 72);
        let depth = corner(&v);
        let raw = sao(
            &depth,
            &v,
            &SaoParams {
                blur_radius: 0,
                quad_max_dz: 0.0,
                ..Default::default()
            },
        )
        .unwrap();
        let blurred = sao(&depth, &v, &SaoParams::default()).unwrap();
        // Variation along a row near the crease (constant in expectation).
        let w = v.width as usize;
        let crease = (0..v.height as usize)
            .find(|&y| depth[y * w + w / 2] < 4.0)
            .unwrap();
        let tv = |img: &[f32], y: usize| -> f32 {
            (8..w - 9)
                .map(|x| (img[y * w + x + 1] - img[y * w + x]).abs())
                .sum()
        };
        let y = crease - 2;
        assert!(
            tv(&blurred, y) < 0.5 * tv(&raw, y),
            "{} {}",
            tv(&blurred, y),
            tv(&raw, y)
        );

        // Bilateral: an AO step along a depth edge survives both passes,
        // and sky pixels take no part.
        let (bw, bh) = (40usize, 30usize);
        let bv = view(bw as u32, bh as u32);
        let mut d = vec![6.0f32; bw * bh];
        let mut src = vec![1.0f32; bw * bh];
        for y in 0..bh {
            for x in 0..bw {
                if x < 20 {
                    d[y * bw + x] = 3.0;
                    src[y * bw + x] = 0.25;
                }
            }
        }
        d[5 * bw + 30] = f32::INFINITY;
        src[5 * bw + 30] = 0.0;
        let frame = Frame::new(&d, &bv);
        let p = SaoParams::default();
        let out = blur_pass(&blur_pass(&src, &frame, &p, true), &frame, &p, false);
        for (i, &o) in out.iter().enumerate() {
            let expected = if i == 5 * bw + 30 {
                1.0
            } else if i % bw < 20 {
                0.25
            } else {
                1.0
            };
            assert!((o - expected).abs() < 1e-6, "pixel {i}: {o}");
        }
        // Without the edge the same step is smoothed.
        let flat = Frame::new(&vec![3.0f32; bw * bh], &bv);
        let out = blur_pass(&src, &flat, &p, true);
        assert!(out[bw + 19] > 0.3 && out[bw + 20] < 0.95);
    }
}
