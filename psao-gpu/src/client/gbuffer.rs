//! What the reconstruction reads per pixel, borrowed from wherever the
//! caller keeps it: a renderer's own arrays, or psao-eval's `GBuffer`
//! (feature `baseline`).

use glam::Vec3;

use crate::error::GpuError;

/// The instance id of a pixel that sees nothing (its AO is 1), as in
/// psao-eval's G-buffer.
pub const NO_INSTANCE: u32 = u32::MAX;

/// Per-pixel surface attributes, one value per pixel in each slice.
#[derive(Clone, Copy, Debug)]
pub struct GBufferSlices<'a> {
    /// World position of the surface seen.
    pub position: &'a [Vec3],
    /// Unit world shading normal.
    pub normal: &'a [Vec3],
    /// The instance seen (its id in the mirror), or [`NO_INSTANCE`].
    pub instance: &'a [u32],
    /// The surface's position in its mesh's bind space (the undeformed
    /// vertices interpolated like the deformed ones), which pixels of
    /// point format 1 instances are looked up by (spec/wire-format.md
    /// 6.1); may be empty when the mirror holds no such instance.
    pub bind_position: &'a [Vec3],
    /// The bind-space normal, facing as `normal` does (empty with
    /// `bind_position`).
    pub bind_normal: &'a [Vec3],
}

impl GBufferSlices<'_> {
    /// Number of pixels, once [`check`](Self::check) passed.
    pub fn pixels(&self) -> usize {
        self.instance.len()
    }

    /// Checks that the slices have the same length, the bind-space ones
    /// or none (the fields are public, so nothing else does).
    pub fn check(&self) -> Result<(), GpuError> {
        let n = self.instance.len();
        if self.position.len() != n || self.normal.len() != n {
            return Err(GpuError::Input(format!(
                "G-buffer slices of different lengths: {} positions, {} normals, {n} instance ids",
                self.position.len(),
                self.normal.len()
            )));
        }
        let bind = (self.bind_position.len(), self.bind_normal.len());
        if bind != (0, 0) && bind != (n, n) {
            return Err(GpuError::Input(format!(
                "G-buffer bind-space slices must be empty or one per pixel: {} bind positions, {} bind normals, {n} instance ids",
                bind.0, bind.1
            )));
        }
        Ok(())
    }
}

#[cfg(feature = "baseline")]
impl<'a> From<&'a psao_eval::GBuffer> for GBufferSlices<'a> {
    fn from(g: &'a psao_eval::GBuffer) -> Self {
        GBufferSlices {
            position: &g.position,
            normal: &g.normal,
            instance: &g.instance,
            bind_position: &g.bind_position,
            bind_normal: &g.bind_normal,
        }
    }
}
