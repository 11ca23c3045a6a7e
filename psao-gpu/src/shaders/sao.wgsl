// Scalable Ambient Obscurance (McGuire, Mara and Luebke, HPG 2012) as
// compute passes: the same passes and constants as psao-scene's CPU
// baseline (psao-eval/src/sao.rs), so that the client's reconstruction
// and SAO can be timed on the same device. Entry points, in order:
// `pyramid` (the rotated-grid z pyramid as source pixels of every texel),
// `obscurance` (the sample pass), `quad` (the 2 x 2 bilateral box filter),
// `blur` (one bilateral 1D pass, run horizontally then vertically).

struct Params {
    width: u32,
    height: u32,
    // Focal length in pixels.
    focal: f32,
    radius: f32,
    samples: u32,
    spiral_turns: f32,
    intensity: f32,
    bias: f32,
    epsilon: f32,
    contrast: f32,
    mip_levels: u32,
    log_q: u32,
    quad_max_dz: f32,
    blur_radius: u32,
    blur_stride: u32,
    // blur_edge_sharpness / blur_depth_range.
    blur_scale: f32,
    // 10 / TAU (f64) as a 64-bit binary fraction (its integer part, 1,
    // drops out modulo 1): low and high words.
    turn_lo: u32,
    turn_hi: u32,
    // Invocations per row of workgroups.
    row: u32,
    // Blur: 1 horizontal, 0 vertical.
    horizontal: u32,
    // 1: the last pass, which clamps to [0, 1] and writes 1 for sky.
    finish: u32,
    // Texels of the pyramid below level 0.
    texels: u32,
    pad0: u32,
    pad1: u32,
    // Per level m: width, height, offset of its texels in `pyramid`.
    levels: array<vec4<u32>, 16>,
}

const TAU: f32 = 6.2831855;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> depth: array<f32>;
// Source pixel of every texel of levels 1.. (level 0 is the image).
@group(0) @binding(2) var<storage, read> texel_source: array<u32>;
@group(0) @binding(3) var<storage, read> src: array<f32>;
@group(0) @binding(4) var<storage, read_write> dst: array<f32>;
@group(0) @binding(5) var<storage, read_write> pyramid_out: array<u32>;
// Gaussian weight of each blur tap distance, 0..=blur_radius.
@group(0) @binding(6) var<storage, read> gauss: array<f32>;

fn finite1(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn finite3(v: vec3<f32>) -> bool {
    return finite1(v.x) && finite1(v.y) && finite1(v.z);
}

// View-space point of pixel i at depth d (View::view_point).
fn point_at(i: u32, d: f32) -> vec3<f32> {
    let px = f32(i % params.width);
    let py = f32(i / params.width);
    let f = params.focal;
    let dir = vec3<f32>(
        (px + 0.5 - f32(params.width) * 0.5) / f,
        -(py + 0.5 - f32(params.height) * 0.5) / f,
        -1.0,
    );
    return dir * d;
}

// Depth of pixel i, or -1 for sky (not finite, not positive, or a point
// that overflows).
fn z_at(i: u32) -> f32 {
    let d = depth[i];
    if (!finite1(d) || !(d > 0.0) || !finite3(point_at(i, d))) {
        return -1.0;
    }
    return d;
}

@compute @workgroup_size(64)
fn pyramid(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x + gid.y * params.row;
    if (t >= params.texels) {
        return;
    }
    var m = 1u;
    while (m < params.mip_levels && t >= params.levels[m + 1u].z) {
        m = m + 1u;
    }
    let lv = params.levels[m];
    let k = t - lv.z;
    var x = k % lv.x;
    var y = k / lv.x;
    // Down the rotated grid of table 1 to the full-resolution pixel.
    for (var l = m; l > 0u; l = l - 1u) {
        let below = params.levels[l - 1u];
        let sx = min(2u * x + ((y & 1u) ^ 1u), below.x - 1u);
        let sy = min(2u * y + ((x & 1u) ^ 1u), below.y - 1u);
        x = sx;
        y = sy;
    }
    pyramid_out[t] = y * params.width + x;
}

// Low and high words of the 64-bit product of a and b.
fn mul_wide(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xFFFFu;
    let a1 = a >> 16u;
    let b0 = b & 0xFFFFu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xFFFFu) + (p10 & 0xFFFFu);
    let lo = (p00 & 0xFFFFu) | (mid << 16u);
    let hi = p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
    return vec2<u32>(lo, hi);
}

// Eq. 8, AlchemyAO's hash: 10 * ((3x) ^ (y + xy)) radians reduced to
// [0, 2 pi), in fixed point: frac(h * 10 / TAU) with 64 fraction bits.
fn rotation_angle(x: u32, y: u32) -> f32 {
    let h = bitcast<i32>((x * 3u) ^ (y + x * y));
    let a = select(u32(h), u32(-h), h < 0);
    // (a * turn) mod 2^64, turn = turn_hi:turn_lo.
    let low = mul_wide(a, params.turn_lo);
    var lo = low.x;
    var hi = low.y + a * params.turn_hi;
    if (h < 0) {
        // frac(-v) = 2^64 - v modulo 2^64.
        lo = ~lo + 1u;
        hi = ~hi + select(0u, 1u, lo == 0u);
    }
    let f = (f32(hi >> 8u) + f32(hi & 0xFFu) / 256.0) / 16777216.0;
    return min(f * TAU, TAU);
}

// One-sided derivative of the position at i (Frame::derivative).
fn derivative(i: u32, c: vec3<f32>, d: f32, prev: i32, next: i32) -> vec4<f32> {
    var fwd = vec4<f32>(0.0, 0.0, 0.0, -1.0);
    var back = vec4<f32>(0.0, 0.0, 0.0, -1.0);
    if (next >= 0) {
        let zj = z_at(u32(next));
        if (zj > 0.0) {
            fwd = vec4<f32>(point_at(u32(next), zj) - c, abs(zj - d));
        }
    }
    if (prev >= 0) {
        let zj = z_at(u32(prev));
        if (zj > 0.0) {
            back = vec4<f32>(c - point_at(u32(prev), zj), abs(zj - d));
        }
    }
    if (fwd.w >= 0.0 && back.w >= 0.0) {
        return select(fwd, back, back.w < fwd.w);
    }
    if (fwd.w >= 0.0) {
        return fwd;
    }
    return back;
}

fn normalize_or(v: vec3<f32>, fallback: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / sqrt(dot(v, v));
    if (finite1(rcp) && rcp > 0.0) {
        return v * rcp;
    }
    return fallback;
}

// Face normal from screen-space derivatives (eq. 4, Frame::normal).
fn face_normal(x: u32, y: u32, i: u32, c: vec3<f32>, d: f32) -> vec3<f32> {
    let fallback = normalize_or(-c, vec3<f32>(0.0, 0.0, 1.0));
    let w = params.width;
    let dx = derivative(i, c, d, select(-1, i32(i) - 1, x > 0u), select(-1, i32(i) + 1, x + 1u < w));
    let dy = derivative(i, c, d, select(-1, i32(i - w), y > 0u), select(-1, i32(i + w), y + 1u < params.height));
    if (dx.w < 0.0 || dy.w < 0.0) {
        return fallback;
    }
    let n = normalize_or(cross(dy.xyz, dx.xyz), fallback);
    return select(n, -n, dot(n, c) > 0.0);
}

// Eq. 9: the level of a tap at screen distance h.
fn mip_level(h: f32) -> u32 {
    if (h < 1.0) {
        return 0u;
    }
    let msb = firstLeadingBit(u32(h));
    return min(max(msb, params.log_q) - params.log_q, params.mip_levels);
}

fn finish(v: f32, valid: bool) -> f32 {
    if (params.finish == 0u) {
        return v;
    }
    if (valid && finite1(v)) {
        return clamp(v, 0.0, 1.0);
    }
    return 1.0;
}

@compute @workgroup_size(64)
fn obscurance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.row;
    let n_px = params.width * params.height;
    if (i >= n_px) {
        return;
    }
    let d = z_at(i);
    if (d < 0.0) {
        dst[i] = 1.0;
        return;
    }
    let x = i % params.width;
    let y = i / params.width;
    let c = point_at(i, d);
    let n = face_normal(x, y, i, c, d);
    // Eq. 5.
    let r_px = params.radius * params.focal / d;
    let phi = rotation_angle(x, y);
    let r2 = params.radius * params.radius;
    let s = f32(params.samples);
    var sum = 0.0;
    for (var k = 0u; k < params.samples; k = k + 1u) {
        // Eqs. 6-7.
        let alpha = (f32(k) + 0.5) / s;
        let h = r_px * alpha;
        let theta = TAU * alpha * params.spiral_turns + phi;
        let tx = f32(x) + 0.5 + h * cos(theta);
        let ty = f32(y) + 0.5 + h * sin(theta);
        if (!(tx >= 0.0 && ty >= 0.0 && tx < f32(params.width) && ty < f32(params.height))) {
            continue;
        }
        let ux = u32(tx);
        let uy = u32(ty);
        // Eqs. 9-10.
        let m = mip_level(h);
        var j = uy * params.width + ux;
        if (m > 0u) {
            let lv = params.levels[m];
            let texel = min(uy >> m, lv.y - 1u) * lv.x + min(ux >> m, lv.x - 1u);
            j = texel_source[lv.z + texel];
        }
        let zj = z_at(j);
        if (zj < 0.0) {
            continue;
        }
        // Eq. 1.
        let v = point_at(j, zj) - c;
        let vv = dot(v, v);
        if (!(finite1(vv) && vv < r2)) {
            continue;
        }
        let num = max(dot(v, n) + c.z * params.bias, 0.0);
        let term = num / (vv + params.epsilon);
        if (finite1(term)) {
            sum = sum + term;
        }
    }
    let open = max(1.0 - 2.0 * params.intensity / s * sum, 0.0);
    var a = open;
    if (params.contrast != 1.0) {
        a = pow(open, params.contrast);
    }
    dst[i] = finish(a, true);
}

fn close(a: u32, b: u32) -> bool {
    let za = z_at(a);
    let zb = z_at(b);
    return za > 0.0 && zb > 0.0 && abs(za - zb) < params.quad_max_dz;
}

// One invocation per 2 x 2 quad: horizontal pairs, then vertical ones.
@compute @workgroup_size(64)
fn quad(@builtin(global_invocation_id) gid: vec3<u32>) {
    let q = gid.x + gid.y * params.row;
    let qw = (params.width + 1u) / 2u;
    let qh = (params.height + 1u) / 2u;
    if (q >= qw * qh) {
        return;
    }
    let w = params.width;
    let x0 = (q % qw) * 2u;
    let y0 = (q / qw) * 2u;
    let has_x1 = x0 + 1u < w;
    let has_y1 = y0 + 1u < params.height;
    // v[row][column] of the quad.
    var v00 = src[y0 * w + x0];
    var v01 = 0.0;
    var v10 = 0.0;
    var v11 = 0.0;
    if (has_x1) {
        v01 = src[y0 * w + x0 + 1u];
    }
    if (has_y1) {
        v10 = src[(y0 + 1u) * w + x0];
        if (has_x1) {
            v11 = src[(y0 + 1u) * w + x0 + 1u];
        }
    }
    if (has_x1) {
        if (close(y0 * w + x0, y0 * w + x0 + 1u)) {
            let m = 0.5 * (v00 + v01);
            v00 = m;
            v01 = m;
        }
        if (has_y1 && close((y0 + 1u) * w + x0, (y0 + 1u) * w + x0 + 1u)) {
            let m = 0.5 * (v10 + v11);
            v10 = m;
            v11 = m;
        }
    }
    if (has_y1) {
        if (close(y0 * w + x0, (y0 + 1u) * w + x0)) {
            let m = 0.5 * (v00 + v10);
            v00 = m;
            v10 = m;
        }
        if (has_x1 && close(y0 * w + x0 + 1u, (y0 + 1u) * w + x0 + 1u)) {
            let m = 0.5 * (v01 + v11);
            v01 = m;
            v11 = m;
        }
    }
    dst[y0 * w + x0] = finish(v00, z_at(y0 * w + x0) > 0.0);
    if (has_x1) {
        dst[y0 * w + x0 + 1u] = finish(v01, z_at(y0 * w + x0 + 1u) > 0.0);
    }
    if (has_y1) {
        dst[(y0 + 1u) * w + x0] = finish(v10, z_at((y0 + 1u) * w + x0) > 0.0);
        if (has_x1) {
            dst[(y0 + 1u) * w + x0 + 1u] = finish(v11, z_at((y0 + 1u) * w + x0 + 1u) > 0.0);
        }
    }
}

// One bilateral 1D pass (section 2.4).
@compute @workgroup_size(64)
fn blur(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.row;
    let w = params.width;
    let h = params.height;
    if (i >= w * h) {
        return;
    }
    let zi = z_at(i);
    if (zi < 0.0) {
        dst[i] = 1.0;
        return;
    }
    let x = i % w;
    let y = i / w;
    var sum = gauss[0] * src[i];
    var total = gauss[0];
    for (var t = 1u; t <= params.blur_radius; t = t + 1u) {
        let g = gauss[t];
        let off = t * params.blur_stride;
        for (var side = 0u; side < 2u; side = side + 1u) {
            var j = -1;
            if (params.horizontal == 1u) {
                if (side == 0u && x >= off) {
                    j = i32(i - off);
                } else if (side == 1u && x + off < w) {
                    j = i32(i + off);
                }
            } else {
                if (side == 0u && y >= off) {
                    j = i32(i - off * w);
                } else if (side == 1u && y + off < h) {
                    j = i32(i + off * w);
                }
            }
            if (j < 0) {
                continue;
            }
            let zj = z_at(u32(j));
            if (zj < 0.0) {
                continue;
            }
            let weight = g * max(1.0 - params.blur_scale * abs(zj - zi), 0.0);
            if (weight > 0.0) {
                sum = sum + weight * src[u32(j)];
                total = total + weight;
            }
        }
    }
    dst[i] = finish(sum / total, true);
}
