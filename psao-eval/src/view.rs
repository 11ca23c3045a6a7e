//! A pinhole view: a [`Camera`] seen through an image of `width x height`
//! pixels, and the one pixel convention every per-pixel pass shares (the
//! G-buffer, the reference, the PSAO client image and SAO).
//!
//! View space is right-handed with the camera at the origin looking down
//! -Z, +Y up and +X right. Pixel `(px, py)` has `py = 0` at the top row;
//! its centre is at `(px + 0.5, py + 0.5)`. With the focal length in
//! pixels `f = height / (2 tan(fov_y / 2))`, the view-space point of pixel
//! `(px, py)` at depth `d > 0` (distance along the view axis) is
//! `x = (px + 0.5 - width / 2) / f * d`, `y = -(py + 0.5 - height / 2) / f * d`,
//! `z = -d`.

use glam::{Affine3A, Vec3};

use psao_scene::{Camera, SceneError};

/// Largest image side accepted, in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;

/// A camera and an image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// The camera.
    pub camera: Camera,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl View {
    /// A view of `camera` at `width x height`, checked: both sides in
    /// `1..=MAX_IMAGE_SIDE`, a finite eye and target that differ, and a
    /// field of view in (0, pi).
    pub fn new(camera: Camera, width: u32, height: u32) -> Result<View, SceneError> {
        let bad = |reason: &str| SceneError::Camera {
            reason: reason.to_string(),
        };
        if !(1..=MAX_IMAGE_SIDE).contains(&width) || !(1..=MAX_IMAGE_SIDE).contains(&height) {
            return Err(bad("image sides must lie in 1..=16384 pixels"));
        }
        if !camera.eye.is_finite() || !camera.target.is_finite() {
            return Err(bad("eye or target is not finite"));
        }
        if (camera.target - camera.eye).try_normalize().is_none() {
            return Err(bad(
                "the camera looks at its own eye (or too near it for a direction)",
            ));
        }
        if !(camera.fov_y > 0.0 && camera.fov_y < std::f32::consts::PI) {
            return Err(bad("field of view is not in (0, pi)"));
        }
        Ok(View {
            camera,
            width,
            height,
        })
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Focal length in pixels: `height / (2 tan(fov_y / 2))`.
    pub fn focal_px(&self) -> f32 {
        self.height as f32 / (2.0 * (self.camera.fov_y * 0.5).tan())
    }

    /// World-to-view transform (see the module docs for view space).
    pub fn world_to_view(&self) -> Affine3A {
        let c = &self.camera;
        // Y up unless the camera looks (almost) straight up or down.
        let dir = (c.target - c.eye).normalize_or_zero();
        let up = if dir.y.abs() < 1.0 - 1e-6 {
            Vec3::Y
        } else {
            Vec3::Z
        };
        Affine3A::from_mat4(glam::camera::rh::view::look_at_mat4(c.eye, c.target, up))
    }

    /// World-to-clip matrix of this view in the convention of
    /// [`psao_codec::SeenSurfaces`]: a world point `P` with
    /// `c = world_to_clip() * (P, 1)` lies at pixel coordinates
    /// `u = (c.x / c.w + 1) / 2 * width`, `v = (1 - c.y / c.w) / 2 * height`,
    /// the same place as the module's pixel convention puts it, and
    /// `c.w` is its depth (in front of the camera when positive).
    ///
    /// (Not `Camera::view_projection`: that picks its up vector by another
    /// rule near the vertical, and this must match the G-buffer's
    /// [`world_to_view`](Self::world_to_view).)
    pub fn world_to_clip(&self) -> glam::Mat4 {
        let aspect = self.width as f32 / self.height as f32;
        // WebGPU clip space (y up); near and far do not enter x, y or w.
        glam::camera::rh::proj::directx::perspective(self.camera.fov_y, aspect, 1e-3, 1e3)
            * glam::Mat4::from(self.world_to_view())
    }

    /// View-space direction (not normalized, `z = -1`) through the centre
    /// of pixel `(px, py)`.
    pub fn view_dir(&self, px: u32, py: u32) -> Vec3 {
        let f = self.focal_px();
        Vec3::new(
            (px as f32 + 0.5 - self.width as f32 * 0.5) / f,
            -(py as f32 + 0.5 - self.height as f32 * 0.5) / f,
            -1.0,
        )
    }

    /// View-space point of pixel `(px, py)` at depth `d`.
    pub fn view_point(&self, px: u32, py: u32, depth: f32) -> Vec3 {
        self.view_dir(px, py) * depth
    }
}
