//! Point AO with ray queries: the compute pass of `shaders/ao.wgsl`, which
//! samples, estimates and offsets rays exactly as psao-scene's CPU tracer
//! does, so that the same seed gives the same rays on both; and the pass of
//! `shaders/changed.wgsl`, which compares the new AO with what clients hold
//! on the GPU and hands back only the points worth sending.

use psao_codec::{SentPoint, Thresholds, normal_table};
use psao_scene::{AoParams, AoResult, ChangedPoints, Estimator, RayJob, morton_order};

use crate::context::{GpuContext, storage_layout, uniform_layout};
use crate::error::GpuError;
use crate::server::accel::GpuScene;

/// Threads per workgroup of the AO pass (the shader's `workgroup_size`).
const WORKGROUP: u32 = 64;

/// Invocations of the AO pass per point (the shader's `LANES`): the
/// interleaved partial sums of the CPU tracer, so both add a point's ray
/// scores in the same order.
const LANES: u32 = psao_scene::RAY_SUM_LANES;

// A point's invocations share one workgroup (the shader adds their sums
// from workgroup memory).
const _: () = assert!(WORKGROUP.is_multiple_of(LANES));

/// Points per block of [`spread_blocks`].
const SPREAD_BLOCK: usize = 64;

/// Most points traced in one dispatch (4 MiB of points: within every
/// device's storage binding limit, and short enough for a watchdog).
const CHUNK: usize = 1 << 18;

/// Single-ray jobs per invocation (the shader's `JOBS_PER`): a point's
/// frame is worked out once for its run of them.
const JOBS_PER: usize = 4;

/// Most single rays cast in one dispatch ([`GpuAo::cast_rays`]): 8 MiB of
/// jobs, within every device's storage binding limit.
pub const JOB_CHUNK: usize = 1 << 20;

/// The shader's `Params`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    radius: f32,
    bias: f32,
    rays: u32,
    estimator: u32,
    seed_lo: u32,
    seed_hi: u32,
    count: u32,
    row: u32,
}

impl Params {
    /// The shader's parameters for `p`, `count` points (or jobs) and
    /// `row` invocations per row of workgroups.
    fn new(p: &AoParams, count: usize, row: u32) -> Params {
        Params {
            radius: p.radius,
            bias: p.bias,
            rays: p.rays,
            estimator: match p.estimator {
                Estimator::ClosestHit => 0,
                Estimator::LaineKarras => 1,
            },
            seed_lo: p.seed as u32,
            seed_hi: (p.seed >> 32) as u32,
            count: count as u32,
            row,
        }
    }
}

/// The compare pass's `Params`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CompareParams {
    count: u32,
    row: u32,
    first: u32,
    ao_steps: u32,
    position_quanta: f32,
    normal_cos: f32,
    pad: [u32; 2],
}

/// The compare pass's `Sent` (a [`SentPoint`]).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SentGpu {
    frac: [f32; 3],
    word: u32,
    normal: [f32; 3],
    cell: u32,
}

/// The AO compute pipeline and the pass that compares its results with
/// what clients hold.
#[derive(Debug)]
pub struct GpuAo {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    cast: wgpu::ComputePipeline,
    cast_layout: wgpu::BindGroupLayout,
    compare: wgpu::ComputePipeline,
    compare_layout: wgpu::BindGroupLayout,
    normal_table: wgpu::Buffer,
}

/// A batch of points in Morton order: neighbouring invocations trace
/// neighbouring points (coherent rays), as the CPU backend does.
struct Sorted {
    /// Input index of each sorted point.
    order: Vec<usize>,
    pts: Vec<[f32; 4]>,
    nrm: Vec<[f32; 4]>,
    ids: Vec<u32>,
}

/// `order` cut into blocks of [`SPREAD_BLOCK`] points, each kept whole
/// (coherent rays nearby), with the blocks spread over the dispatch in
/// a scrambled order, so that a driver that hands each thread a run of
/// consecutive workgroups gets a share of every region of the scene, not
/// one costly region. lavapipe behaves so: this scramble, or running it
/// with more threads than cores, raise its rays per second by a fifth
/// (BENCHMARKS.md).
fn spread_blocks(order: &[usize]) -> Vec<usize> {
    let blocks: Vec<&[usize]> = order.chunks(SPREAD_BLOCK).collect();
    let mut keys: Vec<(u32, usize)> = (0..blocks.len())
        .map(|b| (psao_scene::hash(b as u32 ^ 0x9e37_79b9), b))
        .collect();
    keys.sort_unstable();
    keys.iter()
        .flat_map(|&(_, b)| blocks[b].iter().copied())
        .collect()
}

impl Sorted {
    fn new(ids: &[u32], points: &[glam::Vec3], normals: &[glam::Vec3]) -> Sorted {
        let order = spread_blocks(&morton_order(points));
        Sorted {
            pts: order
                .iter()
                .map(|&i| points[i].extend(0.0).to_array())
                .collect(),
            nrm: order
                .iter()
                .map(|&i| normals[i].extend(0.0).to_array())
                .collect(),
            ids: order.iter().map(|&i| ids[i]).collect(),
            order,
        }
    }

    /// Bounded dispatches: within binding limits, and short enough for a
    /// GPU's watchdog.
    fn chunks(&self) -> impl Iterator<Item = std::ops::Range<usize>> + use<> {
        let n = self.order.len();
        (0..n).step_by(CHUNK).map(move |s| s..(s + CHUNK).min(n))
    }
}

impl GpuAo {
    /// Compiles the AO pass.
    pub fn new(ctx: &GpuContext) -> Result<GpuAo, GpuError> {
        ctx.require_ray_queries()?;
        ctx.checked("AO shader compilation", || {
            // The AO pass's bindings; the single-ray pass's add its jobs.
            let entries: Vec<wgpu::BindGroupLayoutEntry> = [wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::AccelerationStructure {
                    vertex_return: false,
                },
                count: None,
            }]
            .into_iter()
            .chain([uniform_layout(1)])
            .chain([2, 3, 4].map(|b| storage_layout(b, true)))
            .chain([storage_layout(5, false)])
            .chain([6, 7, 8].map(|b| storage_layout(b, true)))
            .collect();
            let layout_of = |label, entries| {
                ctx.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some(label),
                        entries,
                    })
            };
            let layout = layout_of("psao-gpu ao layout", &entries[..8]);
            let cast_layout = layout_of("psao-gpu cast layout", &entries);
            let source = include_str!("../shaders/ao.wgsl");
            let pipeline = ctx.compute_pipeline("psao-gpu ao.wgsl", source, &[&layout]);
            let cast = ctx.compute_pipeline_at(
                "psao-gpu ao.wgsl cast",
                source,
                "cast_rays",
                &[&cast_layout],
            );
            let compare_layout =
                ctx.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some("psao-gpu changed layout"),
                        entries: &[
                            uniform_layout(0),
                            storage_layout(1, true),
                            storage_layout(2, true),
                            storage_layout(3, true),
                            storage_layout(4, false),
                            storage_layout(5, false),
                            storage_layout(6, false),
                            storage_layout(7, false),
                        ],
                    });
            let compare = ctx.compute_pipeline(
                "psao-gpu changed.wgsl",
                include_str!("../shaders/changed.wgsl"),
                &[&compare_layout],
            );
            let table: Vec<[f32; 4]> = normal_table()
                .iter()
                .map(|n| n.extend(0.0).to_array())
                .collect();
            let normal_table = ctx.buffer_with(
                "psao-gpu normal table",
                bytemuck::cast_slice(&table),
                wgpu::BufferUsages::STORAGE,
            );
            GpuAo {
                pipeline,
                layout,
                cast,
                cast_layout,
                compare,
                compare_layout,
                normal_table,
            }
        })
    }

    /// AO at points with unit normals and stable ids against `scene`, with
    /// the CPU tracer's sampling ([`psao_scene::AoTracer::trace_ids`]):
    /// with the same parameters both trace the same rays. A non-finite
    /// point is open (1).
    pub fn trace_ids(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        ids: &[u32],
        points: &[glam::Vec3],
        normals: &[glam::Vec3],
        p: &AoParams,
    ) -> Result<AoResult, GpuError> {
        p.validate()?;
        if points.len() != normals.len() || points.len() != ids.len() {
            return Err(GpuError::Input(format!(
                "{} points, {} normals and {} ids",
                points.len(),
                normals.len(),
                ids.len()
            )));
        }
        let n = points.len();
        let rays = n as u64 * p.rays as u64;
        let Some(tlas) = scene.tlas().filter(|_| n > 0) else {
            return Ok(AoResult {
                ao: vec![1.0; n],
                rays,
            });
        };
        let batch = Sorted::new(ids, points, normals);
        let mut sorted = Vec::with_capacity(n);
        for range in batch.chunks() {
            let len = range.len();
            let readback = ctx.checked("AO pass", || {
                let mut enc = ctx.encoder("psao-gpu ao");
                let out = self.record_ao(ctx, scene, tlas, &mut enc, &batch, range, p);
                let readback = ctx.readback("psao-gpu ao readback", out.size());
                enc.copy_buffer_to_buffer(&out, 0, &readback, 0, out.size());
                ctx.queue.submit(Some(enc.finish()));
                readback
            })?;
            let mut ao = ctx.read_f32(&readback)?;
            ao.truncate(len);
            sorted.extend(ao);
        }
        let mut ao = vec![1.0f32; n];
        for (&i, &v) in batch.order.iter().zip(&sorted) {
            ao[i] = v;
        }
        Ok(AoResult { ao, rays })
    }

    /// Traces as [`trace_ids`](Self::trace_ids) and compares each point's
    /// new AO, position and normal with what its clients hold (`sent`, one
    /// record per point; [`SentPoint::changed`]) on the GPU. Only the
    /// changed points and cells are read back: the same [`ChangedPoints`]
    /// as [`ChangedPoints::compare`] on the AO of
    /// [`trace_ids`](Self::trace_ids), except where a value lies within
    /// the rounding of a threshold (a device may fuse or round the
    /// comparison's arithmetic differently from the host).
    #[allow(clippy::too_many_arguments)]
    pub fn trace_changed(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        ids: &[u32],
        points: &[glam::Vec3],
        normals: &[glam::Vec3],
        sent: &[SentPoint],
        p: &AoParams,
        thresholds: &Thresholds,
    ) -> Result<ChangedPoints, GpuError> {
        p.validate()?;
        if points.len() != normals.len() || points.len() != ids.len() || points.len() != sent.len()
        {
            return Err(GpuError::Input(format!(
                "{} points, {} normals, {} ids and {} records of what clients hold",
                points.len(),
                normals.len(),
                ids.len(),
                sent.len()
            )));
        }
        let n = points.len();
        let Some(tlas) = scene.tlas().filter(|_| n > 0) else {
            let open = AoResult {
                ao: vec![1.0; n],
                rays: n as u64 * p.rays as u64,
            };
            return Ok(ChangedPoints::compare(&open, sent, thresholds)?);
        };
        // The cells the batch names, numbered densely (the caller's
        // numbers may be sparse and large): one bit per cell, kept across
        // the chunks.
        let mut cell_ids: Vec<u32> = sent
            .iter()
            .filter(|s| s.word.is_allocated())
            .map(|s| s.cell)
            .collect();
        cell_ids.sort_unstable();
        cell_ids.dedup();
        let dense = |cell: u32| cell_ids.binary_search(&cell).unwrap_or(0) as u32;
        let bitset_bytes = (cell_ids.len() as u64).div_ceil(32) * 4;
        let limit = ctx.device.limits().max_storage_buffer_binding_size;
        if bitset_bytes > limit {
            return Err(GpuError::Limits {
                what: "bytes of the listed-cell bits (one bit per cell)",
                needed: bitset_bytes,
                limit,
            });
        }
        let batch = Sorted::new(ids, points, normals);
        let listed = ctx.checked("listed-cell bits", || {
            ctx.storage_out("psao-gpu listed cells", bitset_bytes)
        })?;
        let mut found: Vec<(usize, f32)> = Vec::new();
        let mut out = ChangedPoints {
            rays: n as u64 * p.rays as u64,
            ..ChangedPoints::default()
        };
        for range in batch.chunks() {
            let sent_sorted: Vec<SentGpu> = batch.order[range.clone()]
                .iter()
                .map(|&i| {
                    let s = &sent[i];
                    SentGpu {
                        frac: s.frac.to_array(),
                        word: s.word.0,
                        normal: s.normal.to_array(),
                        cell: if s.word.is_allocated() {
                            dense(s.cell)
                        } else {
                            u32::MAX
                        },
                    }
                })
                .collect();
            let (first, len) = (range.start, range.len());
            let (pairs, listed_cells) = self.changed_chunk(
                ctx,
                scene,
                tlas,
                &batch,
                range,
                &sent_sorted,
                &listed,
                p,
                thresholds,
            )?;
            for [at, bits] in pairs {
                let at = at as usize;
                if !(first..first + len).contains(&at) {
                    return Err(GpuError::Rejected {
                        what: "changed points",
                        details: format!(
                            "point {at} outside the dispatch {first}..{}",
                            first + len
                        ),
                    });
                }
                found.push((batch.order[at], f32::from_bits(bits)));
            }
            for c in listed_cells {
                let Some(&cell) = cell_ids.get(c as usize) else {
                    return Err(GpuError::Rejected {
                        what: "changed cells",
                        details: format!("cell {c} of {}", cell_ids.len()),
                    });
                };
                out.cells.push(cell);
            }
        }
        found.sort_unstable_by_key(|x| x.0);
        if let Some(w) = found.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(GpuError::Rejected {
                what: "changed points",
                details: format!("point {} listed twice", w[0].0),
            });
        }
        out.changed = found.iter().map(|x| x.0 as u32).collect();
        out.ao = found.iter().map(|x| x.1).collect();
        out.cells.sort_unstable();
        out.cells.dedup();
        Ok(out)
    }

    /// Traces and compares one chunk of a sorted batch; reads back the
    /// counts, then only the listed (batch index, AO bits) pairs and cells.
    #[allow(clippy::too_many_arguments)]
    fn changed_chunk(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        tlas: &wgpu::Tlas,
        batch: &Sorted,
        range: std::ops::Range<usize>,
        sent: &[SentGpu],
        listed: &wgpu::Buffer,
        p: &AoParams,
        th: &Thresholds,
    ) -> Result<(Vec<[u32; 2]>, Vec<u32>), GpuError> {
        let len = range.len();
        let grid = ctx.grid(len, WORKGROUP);
        let params = CompareParams {
            count: len as u32,
            row: grid.0 * WORKGROUP,
            first: range.start as u32,
            ao_steps: th.ao_steps as u32,
            position_quanta: th.position_quanta,
            normal_cos: th.normal_cos,
            pad: [0; 2],
        };
        let (counts, pairs, cells, counts_back) = ctx.checked("compare pass", || {
            let mut enc = ctx.encoder("psao-gpu changed");
            let ao = self.record_ao(ctx, scene, tlas, &mut enc, batch, range, p);
            let uniform = ctx.uniform("psao-gpu changed params", &params);
            let sent = ctx.buffer_with(
                "psao-gpu sent",
                bytemuck::cast_slice(sent),
                wgpu::BufferUsages::STORAGE,
            );
            let counts = ctx.storage_out("psao-gpu changed counts", 8);
            let pairs = ctx.storage_out("psao-gpu changed points", len as u64 * 8);
            let cells = ctx.storage_out("psao-gpu changed cells", len as u64 * 4);
            let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("psao-gpu changed bind"),
                layout: &self.compare_layout,
                entries: &[
                    (0, uniform.as_entire_binding()),
                    (1, ao.as_entire_binding()),
                    (2, sent.as_entire_binding()),
                    (3, self.normal_table.as_entire_binding()),
                    (4, counts.as_entire_binding()),
                    (5, pairs.as_entire_binding()),
                    (6, cells.as_entire_binding()),
                    (7, listed.as_entire_binding()),
                ]
                .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource }),
            });
            GpuContext::record_pass(&mut enc, "psao-gpu changed", &self.compare, &[&bind], grid);
            let counts_back = ctx.readback("psao-gpu changed counts", 16);
            enc.copy_buffer_to_buffer(&counts, 0, &counts_back, 0, 8);
            ctx.queue.submit(Some(enc.finish()));
            (counts, pairs, cells, counts_back)
        })?;
        drop(counts);
        let n = ctx.read::<u32>(&counts_back)?;
        let (changed, listed_cells) = (n[0] as usize, n[1] as usize);
        if changed > len || listed_cells > changed {
            return Err(GpuError::Rejected {
                what: "changed-point counts",
                details: format!("{changed} points and {listed_cells} cells of {len}"),
            });
        }
        if changed == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        // Only what was listed crosses back.
        let (pairs_back, cells_back) = ctx.checked("changed readback", || {
            let mut enc = ctx.encoder("psao-gpu changed readback");
            let pairs_back = ctx.readback("psao-gpu changed points", changed as u64 * 8);
            enc.copy_buffer_to_buffer(&pairs, 0, &pairs_back, 0, changed as u64 * 8);
            let cells_back = ctx.readback("psao-gpu changed cells", listed_cells as u64 * 4);
            if listed_cells > 0 {
                enc.copy_buffer_to_buffer(&cells, 0, &cells_back, 0, listed_cells as u64 * 4);
            }
            ctx.queue.submit(Some(enc.finish()));
            (pairs_back, cells_back)
        })?;
        let mut pairs: Vec<[u32; 2]> = ctx.read(&pairs_back)?;
        pairs.truncate(changed);
        let mut cells: Vec<u32> = ctx.read(&cells_back)?;
        cells.truncate(listed_cells);
        Ok((pairs, cells))
    }

    /// The score of each ray of `jobs` (in its order) against `scene`,
    /// as [`psao_scene::AoBackend::cast_rays`] asks: ray `ray` of point
    /// `point`, with the CPU tracer's sampling, and the same arithmetic
    /// as [`trace_ids`](Self::trace_ids), whose AO of a point is
    /// [`psao_scene::ao_of_scores`] of its rays' scores, bit for bit. A
    /// job naming a point or ray out of range is an
    /// [`GpuError::Input`]. Jobs go out in Morton order of their points
    /// (a point's rays and its neighbours' side by side), at most
    /// [`JOB_CHUNK`] a dispatch, each with only the points it names.
    #[allow(clippy::too_many_arguments)]
    pub fn cast_rays(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        ids: &[u32],
        points: &[glam::Vec3],
        normals: &[glam::Vec3],
        jobs: &[RayJob],
        p: &AoParams,
    ) -> Result<Vec<f32>, GpuError> {
        p.validate()?;
        let n = points.len();
        if normals.len() != n || ids.len() != n {
            return Err(GpuError::Input(format!(
                "{n} points, {} normals and {} ids",
                normals.len(),
                ids.len()
            )));
        }
        if let Some((j, job)) = jobs
            .iter()
            .enumerate()
            .find(|(_, job)| job.point as usize >= n || job.ray >= p.rays)
        {
            return Err(GpuError::Input(format!(
                "ray job {j} asks for ray {} of point {}, in a batch of {n} points of {} rays",
                job.ray, job.point, p.rays
            )));
        }
        let Some(tlas) = scene.tlas().filter(|_| !jobs.is_empty()) else {
            // Nothing to hit (or nothing asked): every ray misses.
            return Ok(vec![1.0; jobs.len()]);
        };
        // The jobs by their points in Morton order (blocks spread, as the
        // AO pass orders them), each point's in their order: a counting
        // sort by point.
        let mut start = vec![0usize; n + 1];
        for job in jobs {
            start[job.point as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut by_point = vec![0usize; jobs.len()];
        let mut fill = start.clone();
        for (j, job) in jobs.iter().enumerate() {
            let at = &mut fill[job.point as usize];
            by_point[*at] = j;
            *at += 1;
        }
        // Only the points named (a round of early decisions names few).
        let named: Vec<usize> = (0..n).filter(|&i| start[i + 1] > start[i]).collect();
        let named_pts: Vec<glam::Vec3> = named.iter().map(|&i| points[i]).collect();
        let order: Vec<usize> = spread_blocks(&morton_order(&named_pts))
            .into_iter()
            .flat_map(|at| {
                let i = named[at];
                by_point[start[i]..start[i + 1]].iter().copied()
            })
            .collect();
        let mut scores = vec![1.0f32; jobs.len()];
        for chunk in order.chunks(JOB_CHUNK) {
            // The points this chunk names, each once, in order.
            let (mut pts, mut nrm, mut pid) = (Vec::new(), Vec::new(), Vec::new());
            let mut list: Vec<[u32; 2]> = Vec::with_capacity(chunk.len());
            let mut last = None;
            for &j in chunk {
                let i = jobs[j].point as usize;
                if last != Some(i) {
                    pts.push(points[i].extend(0.0).to_array());
                    nrm.push(normals[i].extend(0.0).to_array());
                    pid.push(ids[i]);
                    last = Some(i);
                }
                list.push([pid.len() as u32 - 1, jobs[j].ray]);
            }
            let readback = ctx.checked("single-ray pass", || {
                let grid = ctx.grid(chunk.len().div_ceil(JOBS_PER), WORKGROUP);
                let params = Params::new(p, chunk.len(), grid.0 * WORKGROUP);
                let out = ctx.storage_out("psao-gpu cast out", (chunk.len() * 4) as u64);
                let points = (&pts[..], &nrm[..], &pid[..]);
                let bind = self.bind(ctx, (scene, tlas), &params, points, &out, Some(&list));
                let mut enc = ctx.encoder("psao-gpu cast");
                GpuContext::record_pass(&mut enc, "psao-gpu cast", &self.cast, &[&bind], grid);
                let readback = ctx.readback("psao-gpu cast readback", out.size());
                enc.copy_buffer_to_buffer(&out, 0, &readback, 0, out.size());
                ctx.queue.submit(Some(enc.finish()));
                readback
            })?;
            let values = ctx.read_f32(&readback)?;
            for (&j, &v) in chunk.iter().zip(&values) {
                scores[j] = v;
            }
        }
        Ok(scores)
    }

    /// The bind group of the AO pass (`jobs` `None`) or of the single-ray
    /// pass (its jobs): the scene's TLAS and alpha masks, `params`, the
    /// points, normals and ids, and `out`. Call inside
    /// [`GpuContext::checked`].
    fn bind(
        &self,
        ctx: &GpuContext,
        (scene, tlas): (&GpuScene, &wgpu::Tlas),
        params: &Params,
        (pts, nrm, ids): (&[[f32; 4]], &[[f32; 4]], &[u32]),
        out: &wgpu::Buffer,
        jobs: Option<&[[u32; 2]]>,
    ) -> wgpu::BindGroup {
        let s = wgpu::BufferUsages::STORAGE;
        let uniform = ctx.uniform("psao-gpu ao params", params);
        let pb = ctx.buffer_with("psao-gpu points", bytemuck::cast_slice(pts), s);
        let nb = ctx.buffer_with("psao-gpu normals", bytemuck::cast_slice(nrm), s);
        let ib = ctx.buffer_with("psao-gpu ids", bytemuck::cast_slice(ids), s);
        let jb = jobs.map(|j| ctx.buffer_with("psao-gpu ray jobs", bytemuck::cast_slice(j), s));
        let entries: Vec<wgpu::BindGroupEntry<'_>> = [
            (0, tlas.as_binding()),
            (1, uniform.as_entire_binding()),
            (2, pb.as_entire_binding()),
            (3, nb.as_entire_binding()),
            (4, ib.as_entire_binding()),
            (5, out.as_entire_binding()),
        ]
        .into_iter()
        .chain(jb.as_ref().map(|b| (8, b.as_entire_binding())))
        .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
        .chain(scene.alpha().bind_entries())
        .collect();
        let layout = if jobs.is_some() {
            &self.cast_layout
        } else {
            &self.layout
        };
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("psao-gpu ao bind"),
            layout,
            entries: &entries,
        })
    }

    /// Records the AO pass over `range` of a sorted batch into `enc` and
    /// returns its output buffer (AO in sorted order). Call inside
    /// [`GpuContext::checked`].
    #[allow(clippy::too_many_arguments)]
    fn record_ao(
        &self,
        ctx: &GpuContext,
        scene: &GpuScene,
        tlas: &wgpu::Tlas,
        enc: &mut wgpu::CommandEncoder,
        batch: &Sorted,
        range: std::ops::Range<usize>,
        p: &AoParams,
    ) -> wgpu::Buffer {
        let n = range.len();
        let grid = ctx.grid(n * LANES as usize, WORKGROUP);
        let params = Params::new(p, n, grid.0 * WORKGROUP);
        let out = ctx.storage_out("psao-gpu ao out", (n.max(4) * 4) as u64);
        let points = (
            &batch.pts[range.clone()],
            &batch.nrm[range.clone()],
            &batch.ids[range],
        );
        let bind = self.bind(ctx, (scene, tlas), &params, points, &out, None);
        GpuContext::record_pass(enc, "psao-gpu ao", &self.pipeline, &[&bind], grid);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shader_declares_the_hosts_lanes_and_workgroup_size() {
        let src = include_str!("../shaders/ao.wgsl");
        for decl in [
            format!("const LANES: u32 = {LANES}u;"),
            format!("const JOBS_PER: u32 = {JOBS_PER}u;"),
            format!("var<workgroup> partial: array<f32, {WORKGROUP}>;"),
        ] {
            assert_eq!(src.matches(&decl).count(), 1, "ao.wgsl lacks `{decl}`");
        }
        // Both entry points (the AO pass and the single-ray pass), each
        // with the host's workgroup size.
        let sized = format!("@workgroup_size({WORKGROUP})");
        assert_eq!(src.matches("@workgroup_size(").count(), 2);
        assert_eq!(src.matches(&sized).count(), 2, "ao.wgsl lacks `{sized}`");
    }
}
