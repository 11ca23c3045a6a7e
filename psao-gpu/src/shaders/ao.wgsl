// AO of points with ray queries: the same sampling, estimators, radius and
// ray offset as psao-scene's CPU tracer (psao-scene/src/trace/ao.rs and
// src/random.rs), so that with the same seed both trace the same rays.
enable wgpu_ray_query;

struct Params {
    // AO radius R.
    radius: f32,
    // Configured ray offset along the normal (before the part that grows
    // with the coordinates).
    bias: f32,
    // Rays per point.
    rays: u32,
    // 0: closest hit, scored min(t, R) / R; 1: Laine-Karras.
    estimator: u32,
    // The 64-bit seed, low and high words.
    seed_lo: u32,
    seed_hi: u32,
    // Points in this dispatch.
    count: u32,
    // Invocations per row of workgroups (the dispatch is 2D past 65535
    // groups).
    row: u32,
}

@group(0) @binding(0) var acc: acceleration_structure;
@group(0) @binding(1) var<uniform> params: Params;
// xyz: world position; w unused.
@group(0) @binding(2) var<storage, read> points: array<vec4<f32>>;
// xyz: normal; w unused.
@group(0) @binding(3) var<storage, read> normals: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> ids: array<u32>;
@group(0) @binding(5) var<storage, read_write> ao: array<f32>;

// Alpha masks (psao-scene's AlphaMask), per instance (the TLAS instances'
// custom data is the instance index).
struct AlphaInfo {
    masked: u32,
    index_offset: u32,
    vertex_alpha_offset: u32,
    uv_offset: u32,
    texel_offset: u32,
    width: u32,
    height: u32,
    cutoff: f32,
    factor: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}
@group(0) @binding(6) var<storage, read> alpha_info: array<AlphaInfo>;
// Triangle indices, vertex alphas (f32 bits), texture coordinates (two f32
// bits each) and texels, at the offsets of the infos.
@group(0) @binding(7) var<storage, read> alpha_data: array<u32>;

fn alpha_f32(i: u32) -> f32 {
    return bitcast<f32>(alpha_data[i]);
}

fn alpha_uv(o: u32, vertex: u32) -> vec2<f32> {
    return vec2<f32>(alpha_f32(o + 2u * vertex), alpha_f32(o + 2u * vertex + 1u));
}

const NONE: u32 = 0xFFFFFFFFu;

// AlphaTexture::wrap: floor(rem_euclid(x, 1) * n), at most n - 1.
fn wrap(x: f32, n: u32) -> u32 {
    var r = x % 1.0;
    if (r < 0.0) {
        r = r + 1.0;
    }
    return min(u32(r * f32(n)), n - 1u);
}

// AlphaMask::solid at barycentrics (u, v) of triangle `prim` of
// `instance`'s mesh (weights 1 - u - v, u, v of its three corners).
fn solid(instance: u32, prim: u32, bary: vec2<f32>) -> bool {
    let info = alpha_info[instance];
    if (info.masked == 0u) {
        return true;
    }
    let w = vec3<f32>(1.0 - bary.x - bary.y, bary.x, bary.y);
    let base = info.index_offset + 3u * prim;
    let v = vec3<u32>(alpha_data[base], alpha_data[base + 1u], alpha_data[base + 2u]);
    var a = info.factor;
    if (info.vertex_alpha_offset != NONE) {
        let o = info.vertex_alpha_offset;
        a = a * (alpha_f32(o + v.x) * w.x + alpha_f32(o + v.y) * w.y + alpha_f32(o + v.z) * w.z);
    }
    if (info.uv_offset != NONE) {
        let o = info.uv_offset;
        let uv = alpha_uv(o, v.x) * w.x + alpha_uv(o, v.y) * w.y + alpha_uv(o, v.z) * w.z;
        var texel = 1.0;
        if (info.width > 0u && info.height > 0u && all(abs(uv) <= vec2<f32>(3.4e38))) {
            let x = wrap(uv.x, info.width);
            let y = wrap(uv.y, info.height);
            texel = f32(alpha_data[info.texel_offset + y * info.width + x]) / 255.0;
        }
        a = a * texel;
    }
    return a >= info.cutoff;
}

// psao-scene's GOLDEN (the step of a point's ray azimuths) and SQRT2 (of
// its Laine-Karras ray lengths), in 32-bit fixed point.
const GOLDEN: u32 = 0x9E3779B9u;
const SQRT2: u32 = 0x6A09E667u;
const TAU: f32 = 6.28318530717958647692;
const PI: f32 = 3.14159265358979323846;

// psao_scene::hash (a PCG-style integer hash).
fn hash(x0: u32) -> u32 {
    let x = x0 * 747796405u + 2891336453u;
    let w = ((x >> ((x >> 28u) + 4u)) ^ x) * 277803737u;
    return (w >> 22u) ^ w;
}

// psao_scene::uniform: a number in [0, 1) for (seed, stream, index).
fn uniform01(stream: u32, index: u32) -> f32 {
    let s = hash(params.seed_lo ^ hash(params.seed_hi));
    let h = hash(s ^ hash(stream ^ hash(index)));
    return f32(h >> 8u) / 16777216.0;
}

// Whether every component is finite (by the exponent bits: compilers may
// assume ordered comparisons never see NaN or infinity).
fn finite3(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7F800000u);
    return all(e != vec3<u32>(0x7F800000u));
}

fn finite1(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7F800000u) != 0x7F800000u;
}

// psao_scene::ray_offset.
fn ray_offset(p: vec3<f32>) -> f32 {
    let m = max(max(abs(p.x), abs(p.y)), abs(p.z));
    return params.bias + m * (1.0 / 2097152.0);
}

// Hit distance along (origin, dir) up to tmax, or tmax on a miss.
fn closest(origin: vec3<f32>, dir: vec3<f32>, tmax: f32) -> f32 {
    var rq: ray_query;
    rayQueryInitialize(&rq, acc, RayDesc(RAY_FLAG_NONE, 0xFFu, 0.0, tmax, origin, dir));
    while (rayQueryProceed(&rq)) {
        // Only alpha-masked (non-opaque) triangles come here.
        let c = rayQueryGetCandidateIntersection(&rq);
        if (c.kind == RAY_QUERY_INTERSECTION_TRIANGLE && solid(c.instance_custom_data, c.primitive_index, c.barycentrics)) {
            rayQueryConfirmIntersection(&rq);
        }
    }
    let hit = rayQueryGetCommittedIntersection(&rq);
    if (hit.kind == RAY_QUERY_INTERSECTION_NONE) {
        return tmax;
    }
    return min(hit.t, tmax);
}

// Whether nothing lies along (origin, dir) up to tmax.
fn misses(origin: vec3<f32>, dir: vec3<f32>, tmax: f32) -> bool {
    var rq: ray_query;
    rayQueryInitialize(&rq, acc, RayDesc(RAY_FLAG_TERMINATE_ON_FIRST_HIT, 0xFFu, 0.0, tmax, origin, dir));
    while (rayQueryProceed(&rq)) {
        let c = rayQueryGetCandidateIntersection(&rq);
        if (c.kind == RAY_QUERY_INTERSECTION_TRIANGLE && solid(c.instance_custom_data, c.primitive_index, c.barycentrics)) {
            rayQueryConfirmIntersection(&rq);
        }
    }
    let hit = rayQueryGetCommittedIntersection(&rq);
    return hit.kind == RAY_QUERY_INTERSECTION_NONE;
}

// Invocations per point: each traces every LANES-th of its point's rays,
// so that neighbouring invocations (one SIMD vector on a CPU driver, part
// of a warp on a GPU) start their rays at the same origin and walk the
// same acceleration-structure nodes around it together. On lavapipe this
// raised closest-hit rays per second by about a seventh against one point
// per invocation (BENCHMARKS.md). The CPU tracer adds its ray scores in
// the same order (psao_scene::RAY_SUM_LANES, which ao.rs checks this
// equals, with the workgroup size below).
const LANES: u32 = 8u;

// Per invocation, the sum over its rays; the point's first invocation adds
// its point's LANES sums in order.
var<workgroup> partial: array<f32, 64>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let invocation = gid.x + gid.y * params.row;
    let i = invocation / LANES;
    let lane = invocation % LANES;
    // 0: trace; 1: AO is 1 (no rays, or no finite origin); 2: no point.
    var state = 2u;
    var sum = 0.0;
    if (i < params.count) {
        state = trace(i, lane, &sum);
    }
    partial[local] = sum;
    // Uniform control flow: every invocation of the workgroup gets here.
    workgroupBarrier();
    if (lane == 0u && state != 2u) {
        if (state == 1u) {
            ao[i] = 1.0;
        } else {
            var total = 0.0;
            for (var l = 0u; l < LANES; l = l + 1u) {
                total = total + partial[local + l];
            }
            ao[i] = total / f32(params.rays);
        }
    }
}

// A point's frame for its rays: where they start, the basis about its
// normal, and its per-point random offsets.
struct Frame {
    // 0: trace; 1: AO is 1 without tracing (no rays, or no finite origin).
    state: u32,
    origin: vec3<f32>,
    n: vec3<f32>,
    t1: vec3<f32>,
    t2: vec3<f32>,
    id: u32,
    shift: u32,
    azimuth: u32,
}

// Point `i`'s frame, as psao_scene::PointRays::new.
fn frame(i: u32) -> Frame {
    var f: Frame;
    f.state = 1u;
    let point = points[i].xyz;
    f.id = ids[i];
    if (params.rays == 0u || !finite3(point)) {
        return f;
    }
    // Normalized as glam's try_normalize (times the reciprocal length), or
    // +Z as the CPU's fallback.
    var n = normals[i].xyz;
    let rcp = 1.0 / length(n);
    if (finite1(rcp) && rcp > 0.0) {
        n = n * rcp;
    } else {
        n = vec3<f32>(0.0, 0.0, 1.0);
    }
    // glam's Vec3::any_orthonormal_pair (Duff et al. 2017), with Rust's
    // signum (the sign bit decides, also for zero).
    let sign = select(1.0, -1.0, (bitcast<u32>(n.z) & 0x80000000u) != 0u);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    f.n = n;
    f.t1 = vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    f.t2 = vec3<f32>(b, sign + n.y * n.y * a, -n.y);
    f.origin = point + n * ray_offset(point);
    if (!finite3(f.origin)) {
        return f;
    }
    f.shift = hash(params.seed_lo ^ hash(f.id ^ hash(params.seed_hi)));
    f.azimuth = hash(f.shift);
    f.state = 0u;
    return f;
}

// The score of ray k of a point with frame f (state 0), as
// psao_scene::PointRays::score: min(t, R) / R, or 1 or 0.
fn score(f: Frame, k: u32) -> f32 {
    let r1 = (f32(k) + uniform01(f.id, 3u * k)) / f32(params.rays);
    let r2 = f32((k * GOLDEN + f.azimuth) >> 8u) / 16777216.0;
    // sin and cos of phi in [0, 2 pi), taken in [-pi, pi) where their
    // accuracy is bounded: sin(x) = -sin(x - pi), cos(x) = -cos(x - pi).
    let phi = TAU * r2 - PI;
    let s = -sin(phi);
    let c = -cos(phi);
    let rr = sqrt(r1);
    let dir = f.t1 * (rr * c) + f.t2 * (rr * s) + f.n * sqrt(max(1.0 - r1, 0.0));
    if (params.estimator == 0u) {
        return closest(f.origin, dir, params.radius) / params.radius;
    }
    let u = f32((k * SQRT2 + f.shift) >> 8u) / 16777216.0;
    if (misses(f.origin, dir, u * params.radius)) {
        return 1.0;
    }
    return 0.0;
}

// Adds to `sum` the scores of rays lane, lane + LANES, ... of point `i`;
// returns 0, or 1 where the point's AO is 1 without tracing (no rays, or
// no finite origin).
fn trace(i: u32, lane: u32, sum: ptr<function, f32>) -> u32 {
    let f = frame(i);
    if (f.state != 0u) {
        return f.state;
    }
    for (var k = lane; k < params.rays; k = k + LANES) {
        *sum = *sum + score(f, k);
    }
    return 0u;
}

// Single rays (psao_scene::AoBackend::cast_rays): job j is ray jobs[j].y
// of point jobs[j].x, its score written to ao[j] (1 for a point with
// nothing to trace from). Invocation i casts jobs JOBS_PER * i to
// JOBS_PER * i + JOBS_PER - 1 (most often rays of one point, its frame
// worked out once for them; on lavapipe that took 0.58x the time of one
// job an invocation, and interleaving the jobs of LANES invocations as
// the AO pass interleaves rays gained nothing: BENCHMARKS.md).
// `params.count` counts the jobs.
@group(0) @binding(8) var<storage, read> jobs: array<vec2<u32>>;

const JOBS_PER: u32 = 4u;

@compute @workgroup_size(64)
fn cast_rays(@builtin(global_invocation_id) gid: vec3<u32>) {
    let invocation = gid.x + gid.y * params.row;
    let first = invocation * JOBS_PER;
    var at = 0xFFFFFFFFu;
    var f: Frame;
    for (var t = 0u; t < JOBS_PER; t = t + 1u) {
        let j = first + t;
        if (j >= params.count) {
            break;
        }
        let job = jobs[j];
        if (job.x != at) {
            f = frame(job.x);
            at = job.x;
        }
        if (f.state != 0u) {
            ao[j] = 1.0;
        } else {
            ao[j] = score(f, job.y);
        }
    }
}
