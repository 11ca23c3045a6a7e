//! Alpha masks on the GPU: per instance, where its mesh's mask lives in
//! flat buffers the AO shader reads to decide whether a candidate hit is
//! solid, exactly as psao-scene's `AlphaMask::solid` does.

use psao_scene::Scene;

use crate::context::GpuContext;
use crate::error::GpuError;

/// "None" in an offset field.
const NONE: u32 = u32::MAX;

/// `AlphaInfo` of `ao.wgsl`, one per instance.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct AlphaInfo {
    /// 1 when the instance's mesh is alpha-masked.
    masked: u32,
    /// First index of the mesh's triangles in the index buffer.
    index_offset: u32,
    /// First vertex alpha, or NONE.
    vertex_alpha_offset: u32,
    /// First texture coordinate, or NONE.
    uv_offset: u32,
    /// First texel.
    texel_offset: u32,
    /// Texture size (0: no texture).
    width: u32,
    height: u32,
    cutoff: f32,
    factor: f32,
    _pad: [u32; 3],
}

impl Default for AlphaInfo {
    fn default() -> Self {
        AlphaInfo {
            masked: 0,
            index_offset: 0,
            vertex_alpha_offset: NONE,
            uv_offset: NONE,
            texel_offset: 0,
            width: 0,
            height: 0,
            cutoff: 0.0,
            factor: 1.0,
            _pad: [0; 3],
        }
    }
}

/// The alpha tables of a scene on the device: per instance an
/// [`AlphaInfo`], and one word buffer holding every masked mesh's triangle
/// indices, vertex alphas (f32 bits), texture coordinates (two f32 bits
/// each) and texels (one per word), at the offsets the infos give.
#[derive(Debug)]
pub(crate) struct AlphaTables {
    info: wgpu::Buffer,
    data: wgpu::Buffer,
}

impl AlphaTables {
    /// The tables of `scene` (every mask's data once per mesh), with each
    /// mesh's triangles in the order of its BLAS (`indices`, per mesh).
    pub(crate) fn new(
        ctx: &GpuContext,
        scene: &Scene,
        indices: &[Vec<u32>],
    ) -> Result<AlphaTables, GpuError> {
        let mut per_mesh = vec![AlphaInfo::default(); scene.meshes.len()];
        let mut data = Vec::<u32>::new();
        let too_big = |len: usize| len as u64 >= u32::MAX as u64;
        for (k, m) in scene.meshes.iter().enumerate() {
            let Some(mask) = &m.alpha else { continue };
            let info = &mut per_mesh[k];
            info.masked = 1;
            info.cutoff = mask.cutoff;
            info.factor = mask.factor;
            info.index_offset = data.len() as u32;
            data.extend_from_slice(&indices[k]);
            if !mask.vertex_alpha.is_empty() {
                info.vertex_alpha_offset = data.len() as u32;
                data.extend(mask.vertex_alpha.iter().map(|a| a.to_bits()));
            }
            if let Some(t) = &mask.texture {
                info.uv_offset = data.len() as u32;
                data.extend(t.uvs.iter().flat_map(|uv| [uv.x.to_bits(), uv.y.to_bits()]));
                info.texel_offset = data.len() as u32;
                info.width = t.width;
                info.height = t.height;
                data.extend(t.alpha.iter().map(|&a| a as u32));
            }
            if too_big(data.len()) {
                break;
            }
        }
        let limit = ctx.device.limits().max_storage_buffer_binding_size;
        let bytes = data.len() as u64 * 4;
        if bytes > limit || too_big(data.len()) {
            return Err(GpuError::Limits {
                what: "bytes of alpha-mask data",
                needed: bytes,
                limit,
            });
        }
        let info: Vec<AlphaInfo> = if scene.instances.is_empty() {
            vec![AlphaInfo::default()]
        } else {
            scene.instances.iter().map(|i| per_mesh[i.mesh]).collect()
        };
        ctx.checked("alpha mask upload", || AlphaTables {
            info: ctx.buffer_with(
                "psao-gpu alpha info",
                bytemuck::cast_slice(&info),
                wgpu::BufferUsages::STORAGE,
            ),
            data: ctx.buffer_with(
                "psao-gpu alpha data",
                bytemuck::cast_slice(&data),
                wgpu::BufferUsages::STORAGE,
            ),
        })
    }

    /// Bind group entries 6 and 7 of `ao.wgsl`.
    pub(crate) fn bind_entries(&self) -> [wgpu::BindGroupEntry<'_>; 2] {
        [
            wgpu::BindGroupEntry {
                binding: 6,
                resource: self.info.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 7,
                resource: self.data.as_entire_binding(),
            },
        ]
    }
}
