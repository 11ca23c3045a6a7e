// The compute pass over a G-buffer (appended to reconstruct.wgsl).

// xyz: world position; w unused.
@group(1) @binding(0) var<storage, read> gbuffer_position: array<vec4<f32>>;
// xyz: unit world normal; w unused.
@group(1) @binding(1) var<storage, read> gbuffer_normal: array<vec4<f32>>;
// Instance id per pixel, 0xFFFFFFFF where nothing was hit.
@group(1) @binding(2) var<storage, read> gbuffer_instance: array<u32>;
@group(1) @binding(3) var<storage, read_write> ao_out: array<f32>;
// x: pixels; y: pixels per row of workgroups.
@group(1) @binding(4) var<uniform> pass_size: vec4<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * pass_size.y;
    if (i >= pass_size.x) {
        return;
    }
    let id = gbuffer_instance[i];
    if (id == 0xFFFFFFFFu) {
        ao_out[i] = 1.0;
        return;
    }
    ao_out[i] = psao_ao(id, gbuffer_position[i].xyz, gbuffer_normal[i].xyz);
}
