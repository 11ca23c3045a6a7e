//! CPU reconstruction of AO from the mirror (paper eq. 2-4, with the
//! spec's second pass at twice the radius): at one point, or at many.
//! The GPU version is psao-gpu's `RECONSTRUCT_WGSL` (docs/c-api.md).

use glam::Vec3;
use psao_codec::{InstanceMirror, reconstruct_ao, world_to_local};

use crate::boundary::{OutArray, call_on, out_ptr, put, slice_in};
use crate::decoder::psao_decoder;
use crate::result::{Failure, psao_result};

/// How a position reaches the instance's grid.
#[derive(Clone, Copy)]
enum Space {
    /// Instance-local (format 0) or bind space (format 1): as given.
    Grid,
    /// World space: through the inverse of the instance's transform.
    World,
}

fn ao_at(inst: &InstanceMirror, space: Space, pos: Vec3, normal: Vec3) -> f32 {
    // As the shader's `psao_ao`: a non-finite input is open (normalizing
    // first would turn a NaN normal into zero, which weighs points when
    // T_n < 0).
    if !pos.is_finite() || !normal.is_finite() {
        return 1.0;
    }
    let (x, n) = match space {
        Space::Grid => (pos, normal.normalize_or_zero()),
        Space::World => {
            // No transform yet: the instance has no place in the world
            // (as `psao_ao` of reconstruct.wgsl, which reports it open).
            let Some(t) = inst.transform() else {
                return 1.0;
            };
            match world_to_local(&t.affine(), pos, normal) {
                Some(local) => local,
                // A singular transform: nothing can be looked up.
                None => return 1.0,
            }
        }
    };
    reconstruct_ao(inst, x, n)
}

fn check_space(inst: &InstanceMirror, id: u32, space: Space) -> Result<(), Failure> {
    if matches!(space, Space::World) && inst.def().bind_space() {
        return Err(Failure::invalid(format!(
            "instance {id} is in bind space (point format 1): look it up by the \
             surface's bind-pose position and normal with psao_decoder_reconstruct"
        )));
    }
    Ok(())
}

/// AO at `n` points of instance `id` into `ao[0..n]`: positions and
/// normals are `3 * n` floats (x, y, z per point). See
/// `psao_decoder_reconstruct`.
///
/// # Safety
///
/// `decoder` is a live decoder; `positions` and `normals` are valid for
/// reads of `3 * n` floats and `ao` for writes of `n` (all NULL with
/// `n == 0`).
unsafe fn reconstruct_many(
    decoder: *mut psao_decoder,
    id: u32,
    space: Space,
    positions: *const f32,
    normals: *const f32,
    n: usize,
    ao: *mut f32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = OutArray::new(ao, n, "ao")?;
        let floats = n
            .checked_mul(3)
            .ok_or_else(|| Failure::invalid(format!("{n} points are too many")))?;
        // SAFETY: valid for `3 * n` reads each (contract).
        let p = unsafe { slice_in(positions, floats, "positions") }?;
        // SAFETY: as above.
        let nr = unsafe { slice_in(normals, floats, "normals") }?;
        let inst = d.instance(id)?;
        check_space(inst, id, space)?;
        let values = p.chunks_exact(3).zip(nr.chunks_exact(3)).map(|(p, nr)| {
            let pos = Vec3::new(p[0], p[1], p[2]);
            ao_at(inst, space, pos, Vec3::new(nr[0], nr[1], nr[2]))
        });
        let mut written = 0usize;
        // SAFETY: `ao` holds `n` floats (contract).
        unsafe { out.fill_iter(n, values, (&mut written).into(), "ao") }
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// AO at a point of instance `id` into `*ao`, with `position` and
/// `normal` in the instance's grid space: instance-local for point format
/// 0, the surface's bind-pose position and normal for point format 1 (a
/// skinned instance). The normal need not be unit length. AO is in
/// `[0, 1]`, 1 open; a point no stored point reaches, or a non-finite
/// input, gets 1. `PSAO_ERROR_NOT_FOUND` for an instance not in the
/// mirror.
///
/// # Safety
///
/// `decoder` is a live decoder; `position` and `normal` point to 3 floats (x, y, z);
/// `ao` is valid for a write.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_reconstruct(
    decoder: *mut psao_decoder,
    id: u32,
    position: *const f32,
    normal: *const f32,
    ao: *mut f32,
) -> psao_result {
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { reconstruct_one(decoder, id, Space::Grid, position, normal, ao) }
}

/// AO at a world-space point of instance `id`: `position` and `normal` go
/// through the inverse of the instance's transform. AO is 1 (open) while
/// the instance has no transform or when it is singular, as in
/// reconstruct.wgsl's `psao_ao`. For point format 0 only:
/// a bind-space instance is `PSAO_ERROR_INVALID_ARGUMENT`.
///
/// # Safety
///
/// As `psao_decoder_reconstruct`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_reconstruct_world(
    decoder: *mut psao_decoder,
    id: u32,
    position: *const f32,
    normal: *const f32,
    ao: *mut f32,
) -> psao_result {
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { reconstruct_one(decoder, id, Space::World, position, normal, ao) }
}

/// # Safety
///
/// As `psao_decoder_reconstruct`.
unsafe fn reconstruct_one(
    decoder: *mut psao_decoder,
    id: u32,
    space: Space,
    position: *const f32,
    normal: *const f32,
    ao: *mut f32,
) -> psao_result {
    let body = |d: &mut psao_decoder| -> Result<(), Failure> {
        let out = out_ptr(ao, "ao")?;
        // SAFETY: point to 3 floats (x, y, z) each (contract).
        let p = unsafe { crate::boundary::read_vec3(position, "position") }?;
        // SAFETY: as above.
        let n = unsafe { crate::boundary::read_vec3(normal, "normal") }?;
        let inst = d.instance(id)?;
        check_space(inst, id, space)?;
        let value = ao_at(inst, space, p, n);
        // SAFETY: valid for a write (contract).
        unsafe { put(out, value) };
        Ok(())
    };
    // SAFETY: `decoder` is live and used by this thread only (contract).
    unsafe { call_on(decoder, body) }
}

/// AO at `n` points of instance `id` in its grid space (as
/// `psao_decoder_reconstruct`): `positions` and `normals` hold `3 * n`
/// floats (x, y, z per point), `ao` receives `n`.
///
/// # Safety
///
/// `decoder` is a live decoder; `positions` and `normals` are valid for
/// reads of `3 * n` aligned floats that nothing writes during the call,
/// and `ao` for writes of `n` floats, not overlapping them (all NULL with
/// `n == 0`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_reconstruct_many(
    decoder: *mut psao_decoder,
    id: u32,
    positions: *const f32,
    normals: *const f32,
    n: usize,
    ao: *mut f32,
) -> psao_result {
    // SAFETY: the contract above is `reconstruct_many`'s.
    unsafe { reconstruct_many(decoder, id, Space::Grid, positions, normals, n, ao) }
}

/// AO at `n` world-space points of instance `id` (as
/// `psao_decoder_reconstruct_world`).
///
/// # Safety
///
/// As `psao_decoder_reconstruct_many`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn psao_decoder_reconstruct_world_many(
    decoder: *mut psao_decoder,
    id: u32,
    positions: *const f32,
    normals: *const f32,
    n: usize,
    ao: *mut f32,
) -> psao_result {
    // SAFETY: the contract above is `reconstruct_many`'s.
    unsafe { reconstruct_many(decoder, id, Space::World, positions, normals, n, ao) }
}
