// The display pass: a full-screen triangle showing two views of the
// G-buffer side by side, "lit" (diffuse * AO + ambient * AO) on the left
// and "AO" (grey = AO) on the right.

@group(0) @binding(0) var gbuffer_normal: texture_2d<f32>;
@group(0) @binding(1) var gbuffer_instance: texture_2d<u32>;
@group(0) @binding(2) var<storage, read> ao: array<f32>;

const BACKGROUND: vec3<f32> = vec3<f32>(0.16, 0.18, 0.22);
const DIFFUSE: f32 = 0.75;
const AMBIENT: f32 = 0.25;

@vertex
fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(corner * 2.0 - 1.0, 0.0, 1.0);
}

@fragment
fn fs(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let size = textureDimensions(gbuffer_instance);
    let canvas = vec2<u32>(frag.xy);
    let view = canvas.x / size.x; // 0: lit, 1: AO
    let pixel = vec2<u32>(canvas.x - view * size.x, canvas.y);
    if (textureLoad(gbuffer_instance, pixel, 0).x == 0xFFFFFFFFu) {
        return vec4<f32>(BACKGROUND, 1.0);
    }
    let a = ao[pixel.x + pixel.y * size.x];
    if (view == 0u) {
        let diffuse = textureLoad(gbuffer_normal, pixel, 0).w;
        return vec4<f32>(vec3<f32>((DIFFUSE * diffuse + AMBIENT) * a), 1.0);
    }
    return vec4<f32>(vec3<f32>(a), 1.0);
}
