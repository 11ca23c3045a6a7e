//! Alpha masks (glTF `alphaMode: MASK`): parts of a surface whose alpha is
//! below a cutoff are holes. No point is spawned in a hole and AO rays pass
//! through holes.

use glam::Vec2;

/// An alpha texture: one byte of alpha per texel, sampled nearest with
/// repeat wrapping (glTF's default sampler).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AlphaTexture {
    /// Texture coordinates per vertex.
    pub uvs: Vec<Vec2>,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Alpha per texel, row by row from the top (`width * height` bytes).
    pub alpha: Vec<u8>,
}

/// Where a mesh is transparent.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AlphaMask {
    /// Alpha below this is a hole (glTF `alphaCutoff`, default 0.5).
    pub cutoff: f32,
    /// The material's constant alpha factor.
    pub factor: f32,
    /// Alpha per vertex (multiplied in; empty for none).
    pub vertex_alpha: Vec<f32>,
    /// An alpha texture (multiplied in).
    pub texture: Option<AlphaTexture>,
}

impl AlphaTexture {
    /// Alpha (0..1) at texture coordinate `uv`.
    pub fn sample(&self, uv: Vec2) -> f32 {
        if self.width == 0 || self.height == 0 || !uv.is_finite() {
            return 1.0;
        }
        let wrap = |x: f32, n: u32| ((x.rem_euclid(1.0) * n as f32) as u32).min(n - 1) as usize;
        let (x, y) = (wrap(uv.x, self.width), wrap(uv.y, self.height));
        self.alpha
            .get(y * self.width as usize + x)
            .map_or(1.0, |&a| a as f32 / 255.0)
    }
}

impl AlphaMask {
    /// Checks the cutoff and factor are finite and the per-vertex arrays
    /// match `vertices`; returns what is wrong.
    pub fn check(&self, vertices: usize) -> Result<(), String> {
        if !self.cutoff.is_finite() || !self.factor.is_finite() {
            return Err("alpha cutoff or factor is not finite".into());
        }
        if !self.vertex_alpha.is_empty() && self.vertex_alpha.len() != vertices {
            return Err(format!(
                "{} vertex alphas for {vertices} vertices",
                self.vertex_alpha.len()
            ));
        }
        if let Some(t) = &self.texture {
            if t.uvs.len() != vertices {
                return Err(format!(
                    "{} texture coordinates for {vertices} vertices",
                    t.uvs.len()
                ));
            }
            if t.alpha.len() as u64 != t.width as u64 * t.height as u64 {
                return Err(format!(
                    "{} alpha bytes for a {}x{} texture",
                    t.alpha.len(),
                    t.width,
                    t.height
                ));
            }
        }
        Ok(())
    }

    /// Alpha at barycentric weights `w` of the triangle with vertices `v`.
    pub fn alpha(&self, v: [u32; 3], w: [f32; 3]) -> f32 {
        let mut a = self.factor;
        let lerp = |f: &dyn Fn(usize) -> Option<f32>| -> Option<f32> {
            Some(f(v[0] as usize)? * w[0] + f(v[1] as usize)? * w[1] + f(v[2] as usize)? * w[2])
        };
        if !self.vertex_alpha.is_empty() {
            a *= lerp(&|i| self.vertex_alpha.get(i).copied()).unwrap_or(1.0);
        }
        if let Some(t) = &self.texture {
            let uv = |i: usize| t.uvs.get(i).copied();
            if let (Some(a0), Some(a1), Some(a2)) =
                (uv(v[0] as usize), uv(v[1] as usize), uv(v[2] as usize))
            {
                a *= t.sample(a0 * w[0] + a1 * w[1] + a2 * w[2]);
            }
        }
        a
    }

    /// Whether the surface is solid at barycentric weights `w` of the
    /// triangle with vertices `v`.
    pub fn solid(&self, v: [u32; 3], w: [f32; 3]) -> bool {
        self.alpha(v, w) >= self.cutoff
    }
}
