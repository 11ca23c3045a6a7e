// The G-buffer pass: every node's mesh, drawn once each (the draw's index
// arrives as the instance index: firstInstance). Per pixel it writes what
// psao_ao (reconstruct.wgsl) looks up by: the surface's position and unit
// normal in world space, or in the mesh's own (bind) space for an instance
// whose points are in bind space; and the mirror's instance id.

struct Camera {
    view_proj: mat4x4<f32>,
    // xyz: the eye, world space.
    eye: vec4<f32>,
    // xyz: unit direction towards the light, world space.
    light: vec4<f32>,
}

struct Draw {
    model: mat4x4<f32>,
    // The inverse transpose of the model's 3x3 part.
    normal: mat4x4<f32>,
    // x: the mirror's instance id; y: 1 when it is looked up in bind space.
    info: vec4<u32>,
}

@group(0) @binding(0) var<uniform> camera: Camera;
@group(0) @binding(1) var<storage, read> draws: array<Draw>;

struct Varyings {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) world_normal: vec3<f32>,
    @location(2) local: vec3<f32>,
    @location(3) local_normal: vec3<f32>,
    @location(4) @interpolate(flat) draw: u32,
}

// `position` and `normal` are the mesh's own (bind pose); `posed` and
// `posed_normal` where the draw puts them (the same, but for a skinned
// or morphing mesh: instance-local, posed by pose.js).
@vertex
fn vs(
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) posed: vec3<f32>,
    @location(3) posed_normal: vec3<f32>,
    @builtin(instance_index) draw: u32,
) -> Varyings {
    let d = draws[draw];
    let world = d.model * vec4<f32>(posed, 1.0);
    var out: Varyings;
    out.clip = camera.view_proj * world;
    out.world = world.xyz;
    out.world_normal = (d.normal * vec4<f32>(posed_normal, 0.0)).xyz;
    out.local = position;
    out.local_normal = normal;
    out.draw = draw;
    return out;
}

struct Targets {
    // xyz: the lookup position; w: 1.
    @location(0) position: vec4<f32>,
    // xyz: the lookup normal; w: the lit view's diffuse term.
    @location(1) normal: vec4<f32>,
    @location(2) instance: u32,
}

fn normalize_or(v: vec3<f32>, fallback: vec3<f32>) -> vec3<f32> {
    let l = length(v);
    if (l > 0.0) {
        return v / l;
    }
    return normalize(fallback);
}

@fragment
fn fs(v: Varyings) -> Targets {
    // The face's normal on the camera's side, from the screen derivatives
    // of the position (x right, y down: their cross product points away).
    let face_world = -cross(dpdx(v.world), dpdy(v.world));
    let face_local = -cross(dpdx(v.local), dpdy(v.local));
    let d = draws[v.draw];
    var n = normalize_or(v.world_normal, face_world);
    var n_local = normalize_or(v.local_normal, face_local);
    // No face is culled. As psao-eval's G-buffer does for a double-sided
    // face, the normals flip where the camera sees the side away from the
    // vertex normals (told by the face, not by the interpolated normal).
    if (dot(face_world, n) < 0.0) {
        n = -n;
        n_local = -n_local;
    }
    var out: Targets;
    if (d.info.y == 1u) {
        out.position = vec4<f32>(v.local, 1.0);
        out.normal = vec4<f32>(n_local, 0.0);
    } else {
        out.position = vec4<f32>(v.world, 1.0);
        out.normal = vec4<f32>(n, 0.0);
    }
    out.normal.w = max(dot(n, camera.light.xyz), 0.0);
    out.instance = d.info.x;
    return out;
}
