// The optional hidden-candidate test of spec/wire-format.md 7.3.1, as
// psao-codec's reconstruct_ao_seen does it on the CPU (without its memo:
// each candidate is tested where it is weighed). Append this text after
// reconstruct.wgsl and call `psao_ao_seen(instance, position, normal,
// world_position)`. It needs two more bindings, group 0 bindings 4-5: the
// view (its WebGPU world-to-clip matrix and size) and what each of its
// pixels sees. They are declared here, not in reconstruct.wgsl, so that a
// shader calling only psao_ao binds nothing more. (WGSL passes no functions
// as arguments, so the cell loops of reconstruct.wgsl are written again
// below with the test in them.)

struct PsaoView {
    to_clip: mat4x4<f32>,
    // xy: width, height in pixels.
    size: vec4<u32>,
}

@group(0) @binding(4) var<uniform> psao_view: PsaoView;
// Two per pixel, row-major, row 0 at the top: (the bits of the world
// position q, the instance id or 0xFFFFFFFF where nothing is seen), (the
// bits of the unit world shading normal m facing the camera, unused).
// Read as u32 so that ids pass through no float.
@group(0) @binding(5) var<storage, read> psao_view_surfaces: array<vec4<u32>>;

// The conditions of 7.3.1 on the surface seen at pixel k that do not
// depend on the pixel being shaded, and then the one that does.
fn psao_seen_pixel_hides(k: u32, p: vec3<f32>, n_p: vec3<f32>, x: vec3<f32>, own: u32, t_n: f32, tol: vec2<f32>) -> bool {
    if (2u * k + 1u >= arrayLength(&psao_view_surfaces)) {
        return false;
    }
    let a = psao_view_surfaces[2u * k];
    let seen = a.w;
    if (seen == 0xFFFFFFFFu) {
        return false;
    }
    let q = bitcast<vec3<f32>>(a.xyz);
    let m = bitcast<vec3<f32>>(psao_view_surfaces[2u * k + 1u].xyz);
    // A NaN or infinite q or m hides nothing (tested on the bits: WGSL
    // lets comparisons assume finite values).
    if (!psao_finite3(q) || !psao_finite3(m)) {
        return false;
    }
    let facing = dot(n_p, m);
    if (seen == own && facing > t_n) {
        return false;
    }
    // A surface leaning over the candidate (neither parallel nor
    // perpendicular to it within the normal's quantization, 11.6 degrees:
    // psao-codec's LEAN_MIN and LEAN_MAX) hides it when a position within
    // its quantization e (tol.y) is behind by r / 100 (tol.x).
    let lean = facing > 0.2011 && facing < 0.9795;
    let limit = select(-tol.x, tol.y - tol.x, lean);
    return facing > 0.0 && dot(p - q, m) < limit && dot(x - q, m) >= 0.0;
}

// Whether the candidate at world p with world normal n_p, weighed for the
// pixel at world x on instance `own`, is hidden (7.3.1).
fn psao_seen_hidden(p: vec3<f32>, n_p: vec3<f32>, x: vec3<f32>, own: u32, t_n: f32, tol: vec2<f32>) -> bool {
    let w = psao_view.size.x;
    let h = psao_view.size.y;
    if (w == 0u || h == 0u) {
        return false;
    }
    let c = psao_view.to_clip * vec4<f32>(p, 1.0);
    if (!psao_finite3(c.xyw) || !(c.w > 0.0)) {
        return false;
    }
    let size = vec2<f32>(psao_view.size.xy);
    let u = (c.x / c.w + 1.0) * 0.5 * size.x;
    let v = (1.0 - c.y / c.w) * 0.5 * size.y;
    if (!(u >= 0.0 && u < size.x && v >= 0.0 && v < size.y)) {
        return false;
    }
    let i0 = min(u32(max(floor(u - 0.5), 0.0)), w - 1u);
    let j0 = min(u32(max(floor(v - 0.5), 0.0)), h - 1u);
    let i1 = min(i0 + 1u, w - 1u);
    let j1 = min(j0 + 1u, h - 1u);
    return psao_seen_pixel_hides(j0 * w + i0, p, n_p, x, own, t_n, tol)
        || psao_seen_pixel_hides(j0 * w + i1, p, n_p, x, own, t_n, tol)
        || psao_seen_pixel_hides(j1 * w + i0, p, n_p, x, own, t_n, tol)
        || psao_seen_pixel_hides(j1 * w + i1, p, n_p, x, own, t_n, tol);
}

// An instance's transforms for the test: local to world (M_3 and t), and
// for normals M_3^-T, with the tolerances of spec/wire-format.md 7.3.1 in
// world units in `tol`: x r / 100, y the quantization bound e.
struct PsaoSeenFrame {
    m: mat3x3<f32>,
    t: vec3<f32>,
    normals: mat3x3<f32>,
    tol: vec2<f32>,
    own: u32,
}

// psao_cell_sums with the test: candidates of weight above 0 that the
// view shows hidden count for nothing.
fn psao_seen_cell_sums(inst: PsaoInstance, found: u32, lo: vec3<f32>, x: vec3<f32>, n: vec3<f32>, r: f32, f: PsaoSeenFrame, xw: vec3<f32>) -> vec3<f32> {
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
        if (a > 0.0) {
            let pw = f.m * p + f.t;
            let nl = f.normals * n_p;
            // As glam's normalize_or_zero (and psao_ao's normal).
            let rcp = 1.0 / length(nl);
            var nw = vec3<f32>(0.0);
            if ((bitcast<u32>(rcp) & 0x7F800000u) != 0x7F800000u && rcp > 0.0) {
                nw = nl * rcp;
            }
            if (psao_seen_hidden(pw, nw, xw, f.own, inst.params.x, f.tol)) {
                continue;
            }
        }
        sum_w = sum_w + a;
        sum = sum + a * (f32(w & 0xFFu) / 255.0);
    }
    return vec3<f32>(sum_w, sum, 1.0);
}

// psao_sums with the test.
fn psao_seen_sums(inst: PsaoInstance, x: vec3<f32>, n: vec3<f32>, r: f32, f: PsaoSeenFrame, xw: vec3<f32>) -> vec2<f32> {
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
                var found = psao_find_cell(inst, key, key & inst.dims.w);
                for (var link = 1u; found != PSAO_EMPTY; link = link + 1u) {
                    let part = psao_seen_cell_sums(inst, found, lo, x, n, r, f, xw);
                    sum_w = sum_w + part.x;
                    sum = sum + part.y;
                    if (part.z == 0.0 || link > 16u || inst.to_local_t.w != 1.0) {
                        break;
                    }
                    found = psao_find_cell(inst, key + link * inst.dims.x, (key + link * 0x9E3779B9u) & inst.dims.w);
                }
            }
        }
    }
    return vec2<f32>(sum_w, sum);
}

// psao_ao with the test of 7.3.1 for a pixel whose world position is
// `world_position` (for an instance of point format 1, `position` and
// `normal` are the bind-space ones, as for psao_ao; the test does not
// apply to it, nor to an instance whose transform's products are not
// finite, and the result is psao_ao's). The same test as psao-codec's
// reconstruct_ao_seen up to rounding: the translation is rebuilt here
// from the inverse's (so it rounds differently far from the origin),
// pow() stands for the cube root, and a candidate's projection onto the
// edge between two pixels may land on the other one.
fn psao_ao_seen(instance: u32, position: vec3<f32>, normal: vec3<f32>, world_position: vec3<f32>) -> f32 {
    if (instance >= arrayLength(&psao_instances)) {
        return 1.0;
    }
    let inst = psao_instances[instance];
    if (inst.params.z == 0.0 || inst.params.w == 1.0) {
        return psao_ao(instance, position, normal);
    }
    // M_3's columns are the normal rows (rows of M_3^T); M_3^-T is the
    // transpose of the to_local columns; t = -M_3 to_local_t.
    let m = mat3x3<f32>(inst.normal_x.xyz, inst.normal_y.xyz, inst.normal_z.xyz);
    let normals = transpose(mat3x3<f32>(inst.to_local_x.xyz, inst.to_local_y.xyz, inst.to_local_z.xyz));
    let det = determinant(m);
    let f = PsaoSeenFrame(m, -(m * inst.to_local_t.xyz), normals, vec2<f32>(inst.origin.w / 100.0, inst.cell_size.w) * pow(abs(det), 1.0 / 3.0), instance);
    if (!psao_finite3(f.t) || !(abs(det) > 1.17549435e-38) || !psao_finite3(vec3<f32>(det, f.tol))) {
        return psao_ao(instance, position, normal);
    }
    if (!psao_finite3(position) || !psao_finite3(normal)) {
        return 1.0;
    }
    let x = inst.to_local_x.xyz * position.x + inst.to_local_y.xyz * position.y + inst.to_local_z.xyz * position.z + inst.to_local_t.xyz;
    let nl = vec3<f32>(dot(inst.normal_x.xyz, normal), dot(inst.normal_y.xyz, normal), dot(inst.normal_z.xyz, normal));
    if (!psao_finite3(x) || !psao_finite3(nl)) {
        return 1.0;
    }
    let rcp = 1.0 / length(nl);
    var n = vec3<f32>(0.0);
    if ((bitcast<u32>(rcp) & 0x7F800000u) != 0x7F800000u && rcp > 0.0) {
        n = nl * rcp;
    }
    let first = psao_seen_sums(inst, x, n, inst.origin.w, f, world_position);
    if (first.x > 0.0) {
        return first.y / first.x;
    }
    let second = psao_seen_sums(inst, x, n, 2.0 * inst.origin.w, f, world_position);
    if (second.x > 0.0) {
        return second.y / second.x;
    }
    return 1.0;
}
