//! What a page reads from a mirror: the changed ranges, the flat buffers
//! of psao-gpu's `reconstruct.wgsl` (its `array<PsaoInstance>`, bucket
//! entries and point words), transforms, and AO per pixel on the CPU
//! (the same psao-codec code as a native client's reconstruction).

use glam::Vec3;
use psao_codec::{
    Change, GPU_RECORD_WORDS, Mirror, gpu_instance_record, reconstruct_ao, world_to_local,
};

use crate::change_kind;

/// The largest instance id the page's dense per-instance table holds: its
/// table is 192 bytes per id up to the largest, so this caps it at 16 MiB
/// (psao-gpu allows ids up to 2^20, for a native renderer's memory).
pub const MAX_GPU_INSTANCE_ID: u32 = (16 << 20) / (GPU_RECORD_WORDS as u32 * 4) - 1;

/// What changed since the last call, flat (see `WasmDecoder::take_changes`).
pub(crate) fn take_changes_flat(mirror: &mut Mirror) -> Vec<u32> {
    let changes = mirror.take_changes();
    let mut out = vec![changes.all as u32];
    for c in changes.items {
        let (kind, id, range) = match c {
            Change::Defined(id) => (change_kind::DEFINED, id, 0..0),
            Change::Removed(id) => (change_kind::REMOVED, id, 0..0),
            Change::Transform(id) => (change_kind::TRANSFORM, id, 0..0),
            Change::Buckets(id, r) => (change_kind::BUCKETS, id, r),
            Change::Words(id, r) => (change_kind::WORDS, id, r),
            // A change a later codec adds: upload everything.
            _ => {
                out[0] = 1;
                continue;
            }
        };
        out.extend([kind, id, range.start, range.end]);
    }
    out
}

/// The mirror as `reconstruct.wgsl`'s bindings 0-2: per instance id (0 to
/// the largest, instances above [`MAX_GPU_INSTANCE_ID`] left out), its
/// record; every instance's bucket entries (key, cell) and words one after
/// another, in id order.
#[derive(Debug)]
pub(crate) struct GpuFlat {
    pub records: Vec<u32>,
    pub buckets: Vec<u32>,
    pub words: Vec<u32>,
}

impl GpuFlat {
    /// The layout of `mirror`, or an error naming an instance id above
    /// [`MAX_GPU_INSTANCE_ID`].
    pub(crate) fn of(mirror: &Mirror) -> Result<GpuFlat, String> {
        let largest = mirror.instances().map(|(id, _)| id).max();
        if let Some(id) = largest.filter(|&id| id > MAX_GPU_INSTANCE_ID) {
            return Err(format!(
                "instance id {id} is above {MAX_GPU_INSTANCE_ID}, the largest the page's GPU table holds"
            ));
        }
        let count = largest.map_or(0, |m| m as usize + 1);
        let mut records = vec![0u32; count.max(1) * GPU_RECORD_WORDS];
        let (mut buckets, mut words) = (Vec::new(), Vec::new());
        for (id, inst) in mirror.instances() {
            let record = gpu_instance_record(inst, (buckets.len() / 2) as u32, words.len() as u32);
            let at = id as usize * GPU_RECORD_WORDS;
            records[at..at + GPU_RECORD_WORDS].copy_from_slice(&record);
            buckets.extend(inst.buckets().iter().flat_map(|e| [e.key, e.cell]));
            words.extend_from_slice(inst.words());
        }
        Ok(GpuFlat {
            records,
            buckets,
            words,
        })
    }
}

/// Instance `id`'s local-to-world transform as 12 floats (the columns of
/// the linear part, then the translation), if the stream gave one.
pub(crate) fn transform12(mirror: &Mirror, id: u32) -> Option<Vec<f32>> {
    Some(mirror.instance(id)?.transform()?.matrix.to_vec())
}

/// AO per pixel from a G-buffer: positions and normals 4 floats a pixel
/// (xyz used; world space, or bind space for an instance in bind space,
/// as `psao_ao` of `reconstruct.wgsl`), instance ids (`0xFFFFFFFF`:
/// nothing, AO 1). Pixels past the shortest input are left out.
pub(crate) fn reconstruct(
    mirror: &Mirror,
    positions: &[f32],
    normals: &[f32],
    ids: &[u32],
) -> Vec<f32> {
    let n = ids.len().min(positions.len() / 4).min(normals.len() / 4);
    (0..n)
        .map(|i| {
            let v = |a: &[f32]| Vec3::new(a[4 * i], a[4 * i + 1], a[4 * i + 2]);
            let Some(inst) = mirror.instance(ids[i]) else {
                return 1.0;
            };
            let (pos, nrm) = (v(positions), v(normals));
            let (x, n) = if inst.def().bind_space() {
                (pos, nrm)
            } else {
                match inst
                    .transform()
                    .and_then(|t| world_to_local(&t.affine(), pos, nrm))
                {
                    Some(local) => local,
                    None => return 1.0,
                }
            };
            reconstruct_ao(inst, x, n)
        })
        .collect()
}
