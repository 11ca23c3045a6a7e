//! Per-pixel AO images on a [`GBuffer`]: ray-traced AO at every pixel (the
//! reference at many rays per pixel, RTAO at a few) and the PSAO client's
//! image reconstructed from a [`Mirror`]. Pixels that see nothing are 1
//! (open) in every image: they add zero error, but they count in averages
//! over the image (RMSE, SSIM and FLIP depend on how much of the image is
//! covered; differences of PSNR between methods on the same G-buffer do
//! not).

use glam::Vec3;

use psao_codec::{
    HiddenMemo, InstanceMirror, LocalFrame, Mirror, SeenSurfaces, reconstruct_ao,
    reconstruct_ao_seen,
};
use rayon::prelude::*;

use crate::gbuffer::{GBuffer, NO_INSTANCE};
use crate::view::View;
use psao_scene::{AoParams, AoTracer, SceneError};

/// Ray-traced AO at every covered pixel of `g` against `tracer`, with the
/// same estimator, radius, bias and sampling as the server's points; pixel
/// `k` (row-major) draws its random numbers as point id `k`. With many
/// rays this is the reference; with 1, 4 or 16 it is per-pixel RTAO.
pub fn ray_traced_ao(
    tracer: &AoTracer,
    g: &GBuffer,
    params: &AoParams,
) -> Result<Vec<f32>, SceneError> {
    g.check()?;
    let covered: Vec<u32> = (0..g.pixels() as u32)
        .filter(|&k| g.instance[k as usize] != NO_INSTANCE)
        .collect();
    let points: Vec<_> = covered.iter().map(|&k| g.position[k as usize]).collect();
    let normals: Vec<_> = covered.iter().map(|&k| g.normal[k as usize]).collect();
    let result = tracer.trace_ids(&covered, &points, &normals, params)?;
    let mut image = vec![1.0f32; g.pixels()];
    for (&k, ao) in covered.iter().zip(result.ao) {
        image[k as usize] = ao;
    }
    Ok(image)
}

/// What the PSAO client reconstructed for one image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClientImage {
    /// AO per pixel (1 = open).
    pub ao: Vec<f32>,
    /// Covered pixels whose instance the mirror does not hold, or holds
    /// without a transform yet (shown open).
    pub unknown: usize,
}

/// The PSAO client's AO image: each covered pixel's world position and
/// normal are taken into its instance's local space with the last
/// transform the mirror received (for an instance of point format 1, its
/// bind-space position and normal are used as they are), and AO is reconstructed from the 2x2x2
/// cells around it (paper eq. 2-4, with the second pass at twice the
/// radius of spec/wire-format.md 7.3). Rows run in parallel; the result
/// does not depend on the thread count. A G-buffer whose attributes do not
/// hold `width x height` values is an error.
pub fn psao_image(mirror: &Mirror, g: &GBuffer) -> Result<ClientImage, SceneError> {
    g.check()?;
    client_image(mirror, g, None)
}

/// [`psao_image`] with the optional test of spec/wire-format.md 7.3.1: a
/// candidate point hidden from `view` behind another surface, one that
/// faces the pixel being shaded, is left out (the G-buffer is what the
/// view sees; [`psao_codec::reconstruct_ao_seen`]). Instances in bind space
/// are reconstructed as by [`psao_image`]. `view` must be the view `g` was
/// made from; a view of another size is an error.
pub fn psao_image_seen(
    mirror: &Mirror,
    g: &GBuffer,
    view: &View,
) -> Result<ClientImage, SceneError> {
    g.check()?;
    if (view.width, view.height) != (g.width, g.height) {
        return Err(SceneError::Camera {
            reason: format!(
                "a {}x{} view for a {}x{} G-buffer",
                view.width, view.height, g.width, g.height
            ),
        });
    }
    if g.pixels() == 0 {
        return client_image(mirror, g, None);
    }
    let seen = SeenSurfaces::new(
        view.world_to_clip(),
        g.width,
        g.height,
        &g.position,
        &g.normal,
        &g.instance,
    )
    .map_err(|e| SceneError::Camera {
        reason: format!("the view's surfaces for the hidden test: {e}"),
    })?;
    // One memo per instance the view sees, shared by every row. (Runs of
    // pixels share an instance, so its ids are gathered run by run.)
    let mut ids: Vec<u32> = Vec::new();
    let mut last = NO_INSTANCE;
    for &id in &g.instance {
        if id != last && id != NO_INSTANCE && !ids.contains(&id) {
            ids.push(id);
        }
        last = id;
    }
    let memos: Vec<(u32, HiddenMemo)> = ids
        .into_iter()
        .filter_map(|id| Some((id, HiddenMemo::new(mirror.instance(id)?, id, &seen))))
        .filter(|(_, memo)| memo.applies())
        .collect();
    client_image(mirror, g, Some(&memos[..]))
}

/// [`psao_image`], with the test of [`psao_image_seen`] for the instances
/// `memos` holds, when given (`g` checked).
fn client_image(
    mirror: &Mirror,
    g: &GBuffer,
    memos: Option<&[(u32, HiddenMemo)]>,
) -> Result<ClientImage, SceneError> {
    let w = g.width as usize;
    let rows: Vec<(Vec<f32>, usize)> = (0..g.height as usize)
        .into_par_iter()
        .map(|py| {
            let mut unknown = 0;
            let mut space = PixelSpace::new(mirror);
            // The last instance's memo, as `space` keeps its frame: runs
            // of pixels share an instance.
            let mut last: Option<(u32, Option<&HiddenMemo>)> = None;
            let row = (py * w..py * w + w)
                .map(|k| {
                    let id = g.instance[k];
                    if id == NO_INSTANCE {
                        return 1.0;
                    }
                    let local = space.local(g, k);
                    match local {
                        Some((inst, (x, n))) => match memo_of(memos, &mut last, id) {
                            Some(memo) => reconstruct_ao_seen(memo, x, n, g.position[k]),
                            None => reconstruct_ao(inst, x, n),
                        },
                        None => {
                            unknown += 1;
                            1.0
                        }
                    }
                })
                .collect();
            (row, unknown)
        })
        .collect();
    let mut image = ClientImage::default();
    image.ao.reserve(g.pixels());
    for (row, unknown) in rows {
        image.ao.extend(row);
        image.unknown += unknown;
    }
    Ok(image)
}

/// The memo `memos` holds for instance `id`, through `last` (the last id
/// asked and its answer).
fn memo_of<'a, 'm>(
    memos: Option<&'a [(u32, HiddenMemo<'m>)]>,
    last: &mut Option<(u32, Option<&'a HiddenMemo<'m>>)>,
    id: u32,
) -> Option<&'a HiddenMemo<'m>> {
    if let Some((last_id, memo)) = *last
        && last_id == id
    {
        return memo;
    }
    let memo = memos?.iter().find(|(i, _)| *i == id).map(|(_, m)| m);
    *last = Some((id, memo));
    memo
}

/// Pixel `k`'s instance in the mirror and its surface point in that
/// instance's lookup space: bind space for an instance of point format 1,
/// else local space through the transform the mirror received. `None` for
/// an uncovered pixel, an instance the mirror does not hold, or one without
/// a usable transform yet.
pub(crate) fn pixel_local<'m>(
    mirror: &'m Mirror,
    g: &GBuffer,
    k: usize,
) -> Option<(&'m InstanceMirror, (Vec3, Vec3))> {
    PixelSpace::new(mirror).local(g, k)
}

/// What the mirror holds for one instance id, for its pixels: the instance
/// and its world-to-local frame (`None` in bind space or without a usable
/// transform); `None` when the mirror does not hold it.
type InstanceSpace<'m> = Option<(&'m InstanceMirror, Option<LocalFrame>)>;

/// [`pixel_local`] for a run of pixels: the last instance looked up and its
/// world-to-local frame are kept, so neighbouring pixels of one instance
/// take one map lookup and one matrix inverse between them (the same
/// arithmetic as [`world_to_local`](psao_codec::world_to_local)).
pub(crate) struct PixelSpace<'m> {
    mirror: &'m Mirror,
    /// The last instance id, and what the mirror holds for it.
    last: Option<(u32, InstanceSpace<'m>)>,
}

impl<'m> PixelSpace<'m> {
    pub(crate) fn new(mirror: &'m Mirror) -> PixelSpace<'m> {
        PixelSpace { mirror, last: None }
    }

    /// As [`pixel_local`].
    pub(crate) fn local(
        &mut self,
        g: &GBuffer,
        k: usize,
    ) -> Option<(&'m InstanceMirror, (Vec3, Vec3))> {
        let id = g.instance[k];
        if id == NO_INSTANCE {
            return None;
        }
        let entry = match self.last {
            Some((last, entry)) if last == id => entry,
            _ => {
                let entry = self.mirror.instance(id).map(|inst| {
                    let frame = if inst.def().bind_space() {
                        None
                    } else {
                        inst.transform().and_then(|t| LocalFrame::new(&t.affine()))
                    };
                    (inst, frame)
                });
                self.last = Some((id, entry));
                entry
            }
        };
        let (inst, frame) = entry?;
        if inst.def().bind_space() {
            // Point format 1: looked up in bind space.
            return Some((inst, (g.bind_position[k], g.bind_normal[k])));
        }
        frame?.map(g.position[k], g.normal[k]).map(|x| (inst, x))
    }
}
