//! What a GPU reconstruction reads per instance: the `PsaoInstance` record
//! of psao-gpu's `reconstruct.wgsl`, as 32-bit words in its std430 layout
//! (docs/c-api.md lists the fields). psao-gpu uploads it as it is; an
//! engine that ports the shader gets it through the C API
//! (`psao_decoder_instance_gpu`), so the inverse transform, its
//! invertibility test and the weight parameters are computed in one place.

use crate::client::mirror::InstanceMirror;
use crate::client::reconstruct::WeightParams;

/// 32-bit words in one [`gpu_instance_record`]: 12 `vec4`s, 192 bytes.
pub const GPU_RECORD_WORDS: usize = 48;

/// The `PsaoInstance` record of `inst`, whose bucket entries start at
/// entry `first_bucket` of the shader's bucket buffer and whose words at
/// word `first_word` of its word buffer. Floats are stored as their bits.
///
/// Words 0-15: the world-to-local transform (columns of the inverse linear
/// part, then its translation; word 15 is 1.0 when cells continue in
/// overflow chains); 16-27: the columns of the local-to-world linear part
/// (rows of its transpose, for normals); 28-31: origin and radius; 32-35:
/// cell size and the quantization noise distance; 36-39 (u32): dims and
/// table size - 1; 40-43 (u32): bucket capacity, cell capacity,
/// `first_bucket`, `first_word`; 44-47: T_n, T_d, 1.0 when the instance
/// can be sampled, 1.0 when it is in bind space. An instance of point
/// format 0 can be sampled when it has a transform that is finite with
/// `|det| > f32::MIN_POSITIVE` (as [`world_to_local`](crate::world_to_local));
/// one in bind space always, looked up by bind-space position and normal
/// (its transform rows are then the identity).
pub fn gpu_instance_record(
    inst: &InstanceMirror,
    first_bucket: u32,
    first_word: u32,
) -> [u32; GPU_RECORD_WORDS] {
    let d = inst.def();
    let w = WeightParams::of(d);
    let identity = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0; 4],
    ];
    let (mut to_local, mut normal) = ([[0.0f32; 4]; 4], [[0.0f32; 4]; 3]);
    let (mut sampled, mut bind) = (0.0f32, 0.0f32);
    if d.bind_space() {
        to_local = identity;
        normal.copy_from_slice(&identity[..3]);
        (sampled, bind) = (1.0, 1.0);
    } else if let Some(t) = inst.transform() {
        let m = t.affine();
        let det = m.matrix3.determinant();
        if m.is_finite() && det.is_finite() && det.abs() > f32::MIN_POSITIVE {
            let inv = m.inverse();
            to_local = [
                inv.matrix3.x_axis.extend(0.0).to_array(),
                inv.matrix3.y_axis.extend(0.0).to_array(),
                inv.matrix3.z_axis.extend(0.0).to_array(),
                inv.translation.extend(0.0).to_array(),
            ];
            // Rows of M^T are the columns of M.
            normal = [
                m.matrix3.x_axis.extend(0.0).to_array(),
                m.matrix3.y_axis.extend(0.0).to_array(),
                m.matrix3.z_axis.extend(0.0).to_array(),
            ];
            sampled = 1.0;
        }
    }
    if d.overflow {
        to_local[3][3] = 1.0;
    }
    let mut out = [0u32; GPU_RECORD_WORDS];
    let floats = to_local
        .iter()
        .chain(&normal)
        .flatten()
        .copied()
        .chain(d.origin.extend(w.radius).to_array())
        .chain(d.cell_size.extend(w.noise).to_array());
    for (o, f) in out.iter_mut().zip(floats) {
        *o = f.to_bits();
    }
    out[36..40].copy_from_slice(&[
        d.dims.x,
        d.dims.y,
        d.dims.z,
        (1u32 << d.table_log2).wrapping_sub(1),
    ]);
    out[40..44].copy_from_slice(&[
        d.bucket_capacity as u32,
        d.cell_capacity as u32,
        first_bucket,
        first_word,
    ]);
    for (o, f) in out[44..].iter_mut().zip([w.t_n, w.t_d, sampled, bind]) {
        *o = f.to_bits();
    }
    out
}
