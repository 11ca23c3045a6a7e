// PSAO reconstruction (paper eq. 2-4 with spec/wire-format.md 7.3) from a
// mirror's flat buffers, as psao-codec's reconstruct_ao does on the CPU.
// Include this text in a shader (a fragment shader of your renderer or the
// compute pass of psao-gpu) and call `psao_ao(instance, position, normal)`
// with a world-space position and unit normal. For an instance of point
// format 1 (spec/wire-format.md 6.1; `psao_bind_space(instance)` is true:
// a skinned or morphing mesh whose points stay in its bind space), pass
// the surface's bind-space position and normal instead: the undeformed
// vertex attributes, interpolated like the deformed ones. A full cell's
// overflow chain (spec/wire-format.md 7.4) is followed. The bindings are
// group 0, bindings 0-3; replace `@group(0)` in the text to move them.

struct PsaoInstance {
    // World-to-local transform: columns of the inverse linear part, and
    // the inverse's translation (w unused, but to_local_t.w: 1 when a full
    // cell continues in an overflow chain, spec/wire-format.md 7.4).
    to_local_x: vec4<f32>,
    to_local_y: vec4<f32>,
    to_local_z: vec4<f32>,
    to_local_t: vec4<f32>,
    // Rows of the transpose of the local-to-world linear part (for
    // normals: n_local = M^T n_world, renormalized).
    normal_x: vec4<f32>,
    normal_y: vec4<f32>,
    normal_z: vec4<f32>,
    // xyz: grid origin; w: interpolation radius r.
    origin: vec4<f32>,
    // xyz: cell size; w: the quantization noise distance |cell_size| / 64.
    cell_size: vec4<f32>,
    // xyz: grid dims; w: table size - 1 (a power of two minus one).
    dims: vec4<u32>,
    // x: bucket capacity; y: cell capacity; z: first bucket entry; w: first word.
    arrays: vec4<u32>,
    // x: T_n; y: T_d; z: 1 when the instance can be sampled (defined, with
    // an invertible transform or in bind space); w: 1 when it is in bind
    // space (point format 1; the to_local and normal rows are then the
    // identity).
    params: vec4<f32>,
}

@group(0) @binding(0) var<storage, read> psao_instances: array<PsaoInstance>;
// (key, cell) per bucket entry, every instance's table one after another.
@group(0) @binding(1) var<storage, read> psao_buckets: array<vec2<u32>>;
// Point words, every instance's cell pool one after another.
@group(0) @binding(2) var<storage, read> psao_words: array<u32>;
// The 256 decoded octahedral normals (xyz; w unused).
@group(0) @binding(3) var<storage, read> psao_normals: array<vec4<f32>, 256>;

// Whether every component is finite (by the exponent bits).
fn psao_finite3(v: vec3<f32>) -> bool {
    let e = bitcast<vec3<u32>>(v) & vec3<u32>(0x7F800000u);
    return all(e != vec3<u32>(0x7F800000u));
}

const PSAO_EMPTY: u32 = 0xFFFFFFFFu;
const PSAO_ALLOC: u32 = 0x80000000u;

// Eq. 2 with the rejections of eq. 3 (psao_codec::weight).
fn psao_weight(p: vec3<f32>, n_p: vec3<f32>, x: vec3<f32>, n_x: vec3<f32>, r: f32, t_n: f32, t_d: f32, noise: f32) -> f32 {
    let facing = dot(n_p, n_x);
    if (!(facing > t_n)) {
        return 0.0;
    }
    let d = p - x;
    let dist = length(d);
    let a = (r - dist) / r;
    if (!(a > 0.0)) {
        return 0.0;
    }
    if (dist > noise) {
        let c = dot(n_p, d) / dist;
        if (c * c >= t_d) {
            return 0.0;
        }
    }
    return a;
}

// The cell pool index of `key` in bucket `bucket`, or PSAO_EMPTY.
fn psao_find_cell(inst: PsaoInstance, key: u32, bucket: u32) -> u32 {
    let cap = inst.arrays.x;
    let first = inst.arrays.z + bucket * cap;
    for (var i = 0u; i < cap; i = i + 1u) {
        let e = psao_buckets[first + i];
        if (e.x == PSAO_EMPTY) {
            return PSAO_EMPTY;
        }
        if (e.x == key) {
            return e.y;
        }
    }
    return PSAO_EMPTY;
}

// (sum of weights, sum of weighted AO, 1 when every slot is allocated)
// over the points of pool cell `found`, whose grid cell's minimum corner
// is `lo`.
fn psao_cell_sums(inst: PsaoInstance, found: u32, lo: vec3<f32>, x: vec3<f32>, n: vec3<f32>, r: f32) -> vec3<f32> {
    let cell = inst.cell_size.xyz;
    let cap = inst.arrays.y;
    let start = inst.arrays.w + found * cap;
    var sum_w = 0.0;
    var sum = 0.0;
    for (var s = 0u; s < cap; s = s + 1u) {
        let w = psao_words[start + s];
        if ((w & PSAO_ALLOC) == 0u) {
            return vec3<f32>(sum_w, sum, 0.0);
        }
        let q = vec3<f32>(vec3<u32>((w >> 16u) & 31u, (w >> 21u) & 31u, (w >> 26u) & 31u));
        let p = lo + ((q + 0.5) / 32.0) * cell;
        let n_p = psao_normals[(w >> 8u) & 0xFFu].xyz;
        let a = psao_weight(p, n_p, x, n, r, inst.params.x, inst.params.y, inst.cell_size.w);
        sum_w = sum_w + a;
        sum = sum + a * (f32(w & 0xFFu) / 255.0);
    }
    return vec3<f32>(sum_w, sum, 1.0);
}

// (sum of weights, sum of weighted AO) over the 2x2x2 cells around x.
fn psao_sums(inst: PsaoInstance, x: vec3<f32>, n: vec3<f32>, r: f32) -> vec2<f32> {
    let origin = inst.origin.xyz;
    let cell = inst.cell_size.xyz;
    let dims = vec3<i32>(inst.dims.xyz);
    let g = clamp((x - origin) / cell - 0.5, vec3<f32>(-2.0), vec3<f32>(inst.dims.xyz) + 1.0);
    let base = vec3<i32>(floor(g));
    var sum_w = 0.0;
    var sum = 0.0;
    for (var dz = 0; dz < 2; dz = dz + 1) {
        for (var dy = 0; dy < 2; dy = dy + 1) {
            for (var dx = 0; dx < 2; dx = dx + 1) {
                let c = base + vec3<i32>(dx, dy, dz);
                if (any(c < vec3<i32>(0)) || any(c >= dims)) {
                    continue;
                }
                let cu = vec3<u32>(c);
                let key = cu.x + cu.y * inst.dims.x * 17u + cu.z * inst.dims.x * inst.dims.y * 31u;
                let lo = origin + vec3<f32>(cu) * cell;
                // The cell's own key, then each link of its overflow chain
                // while the one before is full (spec/wire-format.md 7.4).
                var found = psao_find_cell(inst, key, key & inst.dims.w);
                for (var link = 1u; found != PSAO_EMPTY; link = link + 1u) {
                    let part = psao_cell_sums(inst, found, lo, x, n, r);
                    sum_w = sum_w + part.x;
                    sum = sum + part.y;
                    if (part.z == 0.0 || link > 16u || inst.to_local_t.w != 1.0) {
                        break;
                    }
                    // Link j: key k + j Dx, in bucket (k + j * 0x9E3779B9) mod T.
                    found = psao_find_cell(inst, key + link * inst.dims.x, (key + link * 0x9E3779B9u) & inst.dims.w);
                }
            }
        }
    }
    return vec2<f32>(sum_w, sum);
}

// Whether `instance` keeps its points in bind space (point format 1):
// call psao_ao with the surface's bind-space position and normal.
fn psao_bind_space(instance: u32) -> bool {
    if (instance >= arrayLength(&psao_instances)) {
        return false;
    }
    return psao_instances[instance].params.w == 1.0;
}

// AO at a world position with a unit world normal on `instance`, or 1
// (open) when the instance cannot be sampled or no point has weight.
fn psao_ao(instance: u32, position: vec3<f32>, normal: vec3<f32>) -> f32 {
    if (instance >= arrayLength(&psao_instances)) {
        return 1.0;
    }
    let inst = psao_instances[instance];
    if (inst.params.z == 0.0) {
        return 1.0;
    }
    if (!psao_finite3(position) || !psao_finite3(normal)) {
        return 1.0;
    }
    let x = inst.to_local_x.xyz * position.x + inst.to_local_y.xyz * position.y + inst.to_local_z.xyz * position.z + inst.to_local_t.xyz;
    let nl = vec3<f32>(dot(inst.normal_x.xyz, normal), dot(inst.normal_y.xyz, normal), dot(inst.normal_z.xyz, normal));
    if (!psao_finite3(x) || !psao_finite3(nl)) {
        return 1.0;
    }
    // As glam's normalize_or_zero: times the reciprocal length, or zero
    // (which then gives no point weight unless T_n < 0, as on the CPU).
    let rcp = 1.0 / length(nl);
    var n = vec3<f32>(0.0);
    if ((bitcast<u32>(rcp) & 0x7F800000u) != 0x7F800000u && rcp > 0.0) {
        n = nl * rcp;
    }
    let first = psao_sums(inst, x, n, inst.origin.w);
    if (first.x > 0.0) {
        return first.y / first.x;
    }
    let second = psao_sums(inst, x, n, 2.0 * inst.origin.w);
    if (second.x > 0.0) {
        return second.y / second.x;
    }
    return 1.0;
}
