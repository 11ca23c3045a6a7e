// The compute pass over a view with the hidden-candidate test (appended to
// reconstruct.wgsl and reconstruct_seen.wgsl). The view's surfaces
// (group 0, binding 5) give each pixel's world position and instance.

// Two per pixel: the position and normal reconstruct_seen looks the pixel
// up by (bind space for an instance of point format 1, else world), xyz.
@group(1) @binding(0) var<storage, read> seen_lookup: array<vec4<f32>>;
@group(1) @binding(1) var<storage, read_write> seen_ao_out: array<f32>;
// x: pixels; y: pixels per row of workgroups.
@group(1) @binding(2) var<uniform> seen_pass_size: vec4<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * seen_pass_size.y;
    if (i >= seen_pass_size.x) {
        return;
    }
    let a = psao_view_surfaces[2u * i];
    let id = a.w;
    if (id == 0xFFFFFFFFu) {
        seen_ao_out[i] = 1.0;
        return;
    }
    seen_ao_out[i] = psao_ao_seen(id, seen_lookup[2u * i].xyz, seen_lookup[2u * i + 1u].xyz, bitcast<vec3<f32>>(a.xyz));
}
