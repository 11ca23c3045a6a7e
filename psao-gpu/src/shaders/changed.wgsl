// The points worth sending, compared where they were traced: each point's
// new AO (from the AO pass, still on the GPU) against the word its clients
// hold, with psao-codec's thresholds (SentPoint::changed in
// psao-codec/src/table.rs, the same operations; a device may still fuse a
// multiply and an add, so a value within rounding of a threshold can go
// either way), compacted with atomics into a list of changed points and a
// list of the cells whose held words change (each cell once, numbered
// densely by the host).

struct Params {
    // Points in this dispatch.
    count: u32,
    // Points per row of workgroups (the dispatch is 2D past 65535 groups).
    row: u32,
    // Index of this dispatch's first point in the batch.
    first: u32,
    // Thresholds: AO steps (of 1/255), position quanta, normal cosine.
    ao_steps: u32,
    position_quanta: f32,
    normal_cos: f32,
    pad0: u32,
    pad1: u32,
}

// psao-codec's SentPoint.
struct Sent {
    // New position inside the word's cell, in cell units.
    frac: vec3<f32>,
    // The word clients hold; 0 (no allocation bit): always sent.
    word: u32,
    // New unit normal.
    normal: vec3<f32>,
    // The cell holding the word.
    cell: u32,
}

const ALLOC: u32 = 0x80000000u;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> ao: array<f32>;
@group(0) @binding(2) var<storage, read> sent: array<Sent>;
// Decoded unit normal of each normal code (psao-codec's normal_table).
@group(0) @binding(3) var<storage, read> normal_table: array<vec4<f32>, 256>;
// [0]: changed points so far; [1]: cells listed so far.
@group(0) @binding(4) var<storage, read_write> counts: array<atomic<u32>, 2>;
// (index in the batch, AO bits) of each changed point, in no order.
@group(0) @binding(5) var<storage, read_write> changed: array<vec2<u32>>;
// Cells whose held words change, in no order.
@group(0) @binding(6) var<storage, read_write> cells: array<u32>;
// One bit per cell: listed already (kept across the dispatches of a batch).
@group(0) @binding(7) var<storage, read_write> listed: array<atomic<u32>>;

// psao-codec's quantize_ao: round(clamp(ao, 0, 1) * 255), halves away from
// zero (WGSL's round takes halves to even), NaN to 0.
fn quantize_ao(a: f32) -> u32 {
    var x = 0.0;
    // Not NaN, by its bits (a compiler may fold a == a to true).
    if ((bitcast<u32>(a) & 0x7fffffffu) <= 0x7f800000u) {
        x = clamp(a, 0.0, 1.0) * 255.0;
    }
    let f = floor(x);
    // Exact: x - floor(x) has no rounding below 2^23.
    return u32(f) + select(0u, 1u, x - f >= 0.5);
}

fn is_changed(s: Sent, a: f32) -> bool {
    let w = s.word;
    if ((w & ALLOC) == 0u) {
        return true;
    }
    let q = vec3<f32>(vec3<u32>((w >> 16u) & 31u, (w >> 21u) & 31u, (w >> 26u) & 31u));
    let d = (s.frac - (q + 0.5) / 32.0) * 32.0;
    let q_pos = params.position_quanta;
    let moved = q_pos < 0.0 || d.x * d.x + d.y * d.y + d.z * d.z > q_pos * q_pos;
    let n = normal_table[(w >> 8u) & 0xFFu].xyz;
    let turned = n.x * s.normal.x + n.y * s.normal.y + n.z * s.normal.z < params.normal_cos;
    let q_new = quantize_ao(a);
    let q_old = w & 0xFFu;
    let steps = max(q_new, q_old) - min(q_new, q_old);
    // Fully open while clients hold less: sent whatever the threshold.
    let opened = q_new == 255u && q_old != 255u;
    return moved || turned || steps > params.ao_steps || opened;
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.row;
    if (i >= params.count) {
        return;
    }
    let s = sent[i];
    let a = ao[i];
    if (!is_changed(s, a)) {
        return;
    }
    let k = atomicAdd(&counts[0], 1u);
    changed[k] = vec2<u32>(params.first + i, bitcast<u32>(a));
    if ((s.word & ALLOC) != 0u) {
        let bit = 1u << (s.cell & 31u);
        let before = atomicOr(&listed[s.cell >> 5u], bit);
        if ((before & bit) == 0u) {
            cells[atomicAdd(&counts[1], 1u)] = s.cell;
        }
    }
}
