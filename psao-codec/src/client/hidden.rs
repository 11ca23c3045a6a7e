//! The optional test of spec/wire-format.md 7.3.1: a candidate point that
//! the camera cannot see, because another surface stands in front of it
//! and between it and the pixel being shaded, is left out of eq. 4.
//!
//! Eq. 2-3 weigh a point by its distance and normal alone. Where a thin
//! part stands on a surface (a plate leaning on a floor, a table top over
//! a floor), the dark points under it lie in the same plane, with the same
//! normal, as the floor beside it, and leak into the floor pixels just
//! outside its foot. The reconstruction cannot see the part; the pixels of
//! the view can. [`SeenSurfaces`] holds what each pixel of the view sees
//! (world position, normal facing the camera, instance), and
//! [`reconstruct_ao_seen`] asks it, for every candidate, whether a surface
//! seen near the candidate's own pixel covers the candidate and faces the
//! pixel being shaded.

use std::sync::atomic::{AtomicU8, Ordering};

use glam::{Affine3A, Mat3A, Mat4, Vec3, Vec4};
use thiserror::Error;

use crate::client::mirror::InstanceMirror;
use crate::client::reconstruct::{reconstruct_ao, reconstruct_ao_keeping};

/// The instance id of a pixel that sees nothing.
pub const NO_SURFACE: u32 = u32::MAX;

/// A [`SeenSurfaces`] that cannot be built: what was wrong.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum SeenSurfacesError {
    /// Width or height is 0, or `width x height` does not fit in `usize`.
    #[error(
        "the view must be at least one pixel wide and high, and its pixels countable ({width}x{height})"
    )]
    Empty {
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
    },
    /// A per-pixel slice does not hold `width x height` values.
    #[error("{what} holds {len} values, the view has {pixels} pixels")]
    Length {
        /// Which slice.
        what: &'static str,
        /// Its length.
        len: usize,
        /// `width x height`.
        pixels: usize,
    },
    /// The world-to-clip matrix has a NaN or infinite element.
    #[error("the world-to-clip matrix is not finite")]
    Matrix,
}

/// What each pixel of a view sees, for the test of spec/wire-format.md
/// 7.3.1: the view's world-to-clip matrix and, per pixel (row-major, row 0
/// at the top), the world position, the unit world normal facing the
/// camera, and the instance id ([`NO_SURFACE`] where nothing is seen).
///
/// Clip space is that of wgpu and Vulkan-style projections: a world point
/// `P` maps to `c = to_clip * (P, 1)`; it is in front of the camera when
/// `c.w > 0`, and its pixel coordinates are
/// `u = (c.x / c.w + 1) / 2 * width`, `v = (1 - c.y / c.w) / 2 * height`
/// (pixel `(i, j)` covers `[i, i + 1) x [j, j + 1)`).
///
/// The instance ids must be those the mirror uses ([`NO_SURFACE`] is
/// `u32::MAX`). Normals and positions are taken as given: a pixel whose
/// position or normal is not finite hides nothing.
#[derive(Clone, Copy, Debug)]
pub struct SeenSurfaces<'a> {
    to_clip: Mat4,
    width: u32,
    height: u32,
    position: &'a [Vec3],
    normal: &'a [Vec3],
    instance: &'a [u32],
}

impl<'a> SeenSurfaces<'a> {
    /// Checks and holds a view's surfaces: a finite matrix, a view of at
    /// least one pixel, and one value per pixel in every slice.
    pub fn new(
        to_clip: Mat4,
        width: u32,
        height: u32,
        position: &'a [Vec3],
        normal: &'a [Vec3],
        instance: &'a [u32],
    ) -> Result<SeenSurfaces<'a>, SeenSurfacesError> {
        if width == 0 || height == 0 {
            return Err(SeenSurfacesError::Empty { width, height });
        }
        if !to_clip.is_finite() {
            return Err(SeenSurfacesError::Matrix);
        }
        let pixels = (width as usize)
            .checked_mul(height as usize)
            .ok_or(SeenSurfacesError::Empty { width, height })?;
        for (what, len) in [
            ("position", position.len()),
            ("normal", normal.len()),
            ("instance", instance.len()),
        ] {
            if len != pixels {
                return Err(SeenSurfacesError::Length { what, len, pixels });
            }
        }
        Ok(SeenSurfaces {
            to_clip,
            width,
            height,
            position,
            normal,
            instance,
        })
    }

    /// Whether the candidate at world position `p` with unit world normal
    /// `n_p`, weighed for the pixel at world position `x` on instance
    /// `own`, is hidden (spec/wire-format.md 7.3.1): one of the (up to) four
    /// pixels whose centres surround the candidate's projection sees a
    /// surface that
    /// - is not the candidate's own surface (another instance, or a normal
    ///   `m` with `n_p . m <= t_n`),
    /// - covers the candidate's side (`n_p . m > 0`),
    /// - has `x` on its front side (`(x - q) . m >= 0`, `q` its position),
    /// - and has `p` behind it: `(p - q) . m < -tol`, or, for a surface
    ///   that leans over the candidate (`LEAN_MIN < n_p . m < LEAN_MAX`),
    ///   `(p - q) . m < slack - tol`: a point that may lie behind it within
    ///   its quantization counts as behind.
    ///
    /// `tol` is the spec's `h` and `slack` its `g` (`r / 100` and `e` in
    /// world units); `n_p` is used as given (unit length expected). A
    /// candidate behind the camera or outside the view
    /// (`0 <= u < width`, `0 <= v < height`), or whose clip coordinates
    /// are not finite, is never hidden, and a pixel
    /// whose position or normal is not finite hides nothing. This projects
    /// the world point with the view's matrix; [`reconstruct_ao_seen`]
    /// projects local points with the product of the view's matrix and the
    /// instance's transform, whose rounding may differ for a candidate on
    /// the edge between two pixels.
    #[allow(clippy::too_many_arguments)]
    pub fn hides(
        &self,
        p: Vec3,
        n_p: Vec3,
        x: Vec3,
        own: u32,
        t_n: f32,
        tol: f32,
        slack: f32,
    ) -> bool {
        self.around(self.to_clip * p.extend(1.0))
            .is_some_and(|quad| {
                quad.into_iter().any(|k| {
                    self.pixel_may_hide(k, p, n_p, own, t_n, tol, slack) && self.faces(k, x)
                })
            })
    }

    /// The four pixels (repeated at the view's last column or row) whose
    /// centres surround the projection of a point at clip coordinates `c`,
    /// or `None` when it lies behind the camera or outside the view, or
    /// `c.x`, `c.y` or `c.w` is not finite (an infinite `w` would put any
    /// point at the view's centre).
    fn around(&self, c: Vec4) -> Option<[usize; 4]> {
        if !(c.x.is_finite() && c.y.is_finite() && c.w.is_finite()) || c.w <= 0.0 {
            return None;
        }
        let (w, h) = (self.width as f32, self.height as f32);
        let u = (c.x / c.w + 1.0) * 0.5 * w;
        let v = (1.0 - c.y / c.w) * 0.5 * h;
        if !(u >= 0.0 && u < w && v >= 0.0 && v < h) {
            return None;
        }
        let (wi, hi) = (self.width as usize, self.height as usize);
        // Columns i0, i0 + 1 and rows j0, j0 + 1, clamped to the view.
        let i0 = ((u - 0.5).floor().max(0.0) as usize).min(wi - 1);
        let j0 = ((v - 0.5).floor().max(0.0) as usize).min(hi - 1);
        let i1 = (i0 + 1).min(wi - 1);
        let j1 = (j0 + 1).min(hi - 1);
        Some([j0 * wi + i0, j0 * wi + i1, j1 * wi + i0, j1 * wi + i1])
    }

    /// The conditions of [`hides`](Self::hides) on the surface seen at
    /// pixel `k` that do not depend on the pixel being shaded.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn pixel_may_hide(
        &self,
        k: usize,
        p: Vec3,
        n_p: Vec3,
        own: u32,
        t_n: f32,
        tol: f32,
        slack: f32,
    ) -> bool {
        let seen = self.instance[k];
        if seen == NO_SURFACE {
            return false;
        }
        let (q, m) = (self.position[k], self.normal[k]);
        // A pixel whose surface is not finite hides nothing (as on the GPU).
        if !q.is_finite() || !m.is_finite() {
            return false;
        }
        let facing = n_p.dot(m);
        // The candidate's own surface: its position is quantized (up to
        // |cell_size| / 64 off the surface), so it may lie a little behind
        // the surface it was traced on.
        if seen == own && facing > t_n {
            return false;
        }
        // A surface leaning over the candidate, neither parallel to it nor
        // perpendicular within the normal's quantization: the candidate
        // counts as behind when a position within its quantization `e`
        // is. (A parallel surface may be the one the point lies on, such as
        // a floor of another instance in the same plane; a perpendicular
        // one may not cover it at all.)
        let limit = if facing > LEAN_MIN && facing < LEAN_MAX {
            slack - tol
        } else {
            -tol
        };
        facing > 0.0 && (p - q).dot(m) < limit
    }

    /// Whether the pixel being shaded, at world `x`, is on the front side
    /// of the surface seen at pixel `k`.
    #[inline]
    fn faces(&self, k: usize, x: Vec3) -> bool {
        (x - self.position[k]).dot(self.normal[k]) >= 0.0
    }
}

/// The sine of 11.6 degrees (0.20108) rounded up, 11.6 degrees being the
/// bound on the angle between a normal and its decoded normal
/// (spec/wire-format.md 6): a surface whose normal `m` has `n_p . m` at
/// most this may be perpendicular to the candidate's true normal. The
/// literal, as an `f32`, is the rule (7.3.1).
pub const LEAN_MIN: f32 = 0.2011;
/// The cosine of 11.6 degrees (0.97958) rounded down: a surface with
/// `n_p . m` at least this may be parallel to the candidate's true normal.
pub const LEAN_MAX: f32 = 0.9795;

/// An instance's transforms for the test, in one view: local to world for
/// positions and for normals, local to clip, and the tolerances.
#[derive(Clone, Copy, Debug)]
struct SeenFrame {
    to_world: Affine3A,
    normals: Mat3A,
    to_clip: Mat4,
    tol: f32,
    /// The quantization bound `e` in world units.
    slack: f32,
}

impl SeenFrame {
    /// `None` for an instance in bind space, without a transform, or with
    /// a singular or non-finite one.
    fn of(inst: &InstanceMirror, seen: &SeenSurfaces) -> Option<SeenFrame> {
        let def = inst.def();
        if def.bind_space() {
            return None;
        }
        let to_world = inst.transform()?.affine();
        let det = to_world.matrix3.determinant();
        if !det.is_finite() || det.abs() <= f32::MIN_POSITIVE {
            return None;
        }
        let frame = SeenFrame {
            to_world,
            // Normals map by the inverse transpose of the linear part.
            normals: to_world.matrix3.inverse().transpose(),
            to_clip: seen.to_clip * Mat4::from(to_world),
            tol: def.radius / 100.0 * det.abs().cbrt(),
            // e = |cell_size| / 64, as the weight's `noise` and the GPU
            // record compute it.
            slack: def.cell_size.length() / 64.0 * det.abs().cbrt(),
        };
        // A finite but huge transform can overflow the products.
        let finite = to_world.is_finite()
            && frame.normals.is_finite()
            && frame.to_clip.is_finite()
            && frame.tol.is_finite()
            && frame.slack.is_finite();
        finite.then_some(frame)
    }
}

/// One instance in one view, for [`reconstruct_ao_seen`]: the instance as
/// the mirror holds it, its id, the view's surfaces, the instance's
/// transforms in that view, and what earlier pixels learned about each of
/// its points (whether any surface around it could hide it), so that a
/// point weighed for many pixels is projected once. It borrows the mirror's
/// instance and the view, so neither can change while it lives; make one
/// per instance and view (or frame) and share it between the pixels of that
/// view, threads included.
#[derive(Debug)]
pub struct HiddenMemo<'a> {
    inst: &'a InstanceMirror,
    id: u32,
    seen: SeenSurfaces<'a>,
    /// The instance's transforms in the view, when the test applies.
    frame: Option<SeenFrame>,
    /// Per point word: [`UNKNOWN`], [`NEVER`] or [`MAYBE`] (empty when the
    /// test does not apply).
    state: Vec<AtomicU8>,
}

/// Not yet looked at.
const UNKNOWN: u8 = 0;
/// No surface around the point can hide it, whatever the pixel.
const NEVER: u8 = 1;
/// Some surface around it may hide it: test each pixel.
const MAYBE: u8 = 2;

impl<'a> HiddenMemo<'a> {
    /// Instance `inst`, whose id (the one `seen` names its pixels by) is
    /// `id`, in the view of `seen`; nothing learned yet.
    pub fn new(inst: &'a InstanceMirror, id: u32, seen: &SeenSurfaces<'a>) -> HiddenMemo<'a> {
        let frame = SeenFrame::of(inst, seen);
        let len = if frame.is_some() {
            inst.words().len()
        } else {
            0
        };
        HiddenMemo {
            inst,
            id,
            seen: *seen,
            frame,
            state: (0..len).map(|_| AtomicU8::new(UNKNOWN)).collect(),
        }
    }

    /// Whether the test applies to the instance (local space, with a
    /// usable transform): else [`reconstruct_ao_seen`] is
    /// [`reconstruct_ao`].
    pub fn applies(&self) -> bool {
        self.frame.is_some()
    }
}

/// [`reconstruct_ao`] with the test of spec/wire-format.md 7.3.1 for the
/// instance and view of `memo`: a candidate that the view shows hidden
/// behind another surface, one that faces the pixel being shaded, is left
/// out of both passes.
///
/// `x` and `n` are the pixel's surface point and unit normal in the
/// instance's lookup space, as for [`reconstruct_ao`]; `x_world` is the
/// same point in world space. The test needs a candidate's world position,
/// so it applies to instances in local space with a transform; for an
/// instance in bind space (point format 1), or one without a usable
/// transform, this is [`reconstruct_ao`] ([`HiddenMemo::applies`]). The
/// tolerance `r / 100` and the quantization bound `e = |cell_size| / 64`
/// are scaled from local to world units by the cube root of the
/// transform's determinant.
pub fn reconstruct_ao_seen(memo: &HiddenMemo, x: Vec3, n: Vec3, x_world: Vec3) -> f32 {
    let (inst, id, seen) = (memo.inst, memo.id, &memo.seen);
    let Some(frame) = memo.frame else {
        return reconstruct_ao(inst, x, n);
    };
    let t_n = inst.def().t_n;
    reconstruct_ao_keeping(inst, x, n, |word, p, n_p| {
        let state = memo.state.get(word);
        let known = state.map_or(UNKNOWN, |s| s.load(Ordering::Relaxed));
        if known == NEVER {
            return true;
        }
        let Some(quad) = seen.around(frame.to_clip * p.extend(1.0)) else {
            if let Some(s) = state {
                s.store(NEVER, Ordering::Relaxed);
            }
            return true;
        };
        let pw = frame.to_world.transform_point3(p);
        let nw = (frame.normals * n_p).normalize_or_zero();
        // Which of the four pixels may hide the point, as bits.
        let mut may = 0u8;
        for (bit, &k) in quad.iter().enumerate() {
            if seen.pixel_may_hide(k, pw, nw, id, t_n, frame.tol, frame.slack) {
                may |= 1 << bit;
            }
        }
        if let (UNKNOWN, Some(s)) = (known, state) {
            // Every thread that looks computes the same value (it does not
            // depend on the pixel being shaded), so the order of stores
            // does not matter.
            s.store(if may != 0 { MAYBE } else { NEVER }, Ordering::Relaxed);
        }
        let mut hidden = false;
        for (bit, &k) in quad.iter().enumerate() {
            hidden |= may & (1 << bit) != 0 && seen.faces(k, x_world);
        }
        !hidden
    })
}
