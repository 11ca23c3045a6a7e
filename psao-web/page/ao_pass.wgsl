// The AO pass over the G-buffer, appended to the project's reconstruct.wgsl
// (its bindings are group 0): one invocation per pixel, AO into `ao_out`
// (row-major, top row first; 1 where nothing was hit).

@group(1) @binding(0) var gbuffer_position: texture_2d<f32>;
@group(1) @binding(1) var gbuffer_normal: texture_2d<f32>;
@group(1) @binding(2) var gbuffer_instance: texture_2d<u32>;
@group(1) @binding(3) var<storage, read_write> ao_out: array<f32>;

@compute @workgroup_size(8, 8)
fn reconstruct_gbuffer(@builtin(global_invocation_id) gid: vec3<u32>) {
    let size = textureDimensions(gbuffer_instance);
    if (gid.x >= size.x || gid.y >= size.y) {
        return;
    }
    let pixel = vec2<i32>(gid.xy);
    let i = gid.x + gid.y * size.x;
    let id = textureLoad(gbuffer_instance, pixel, 0).x;
    if (id == 0xFFFFFFFFu) {
        ao_out[i] = 1.0;
        return;
    }
    let position = textureLoad(gbuffer_position, pixel, 0).xyz;
    let normal = textureLoad(gbuffer_normal, pixel, 0).xyz;
    ao_out[i] = psao_ao(id, position, normal);
}
