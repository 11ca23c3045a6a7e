// A small z-buffer triangle rasterizer for the CPU fallback: it fills the
// same G-buffer as gbuffer.wgsl does on the GPU (lookup position, lookup
// normal + diffuse term, instance id), at pixel centres, with perspective-
// correct interpolation, triangles clipped at the near plane and no face
// culled. Pure JavaScript with no DOM, so node can test it.

import { cross, dot, normalize, sub } from "./math.js";

export const NO_INSTANCE = 0xffffffff;

// `meshes`: parseGlb's; `draws`: [{mesh, model, normal, instance, bindSpace}];
// `matrices`: Camera.matrices' ({viewProj, eye, light}). Returns
// {width, height, positions, normals, ids} with 4 floats per pixel in
// positions and normals (normals' w: the diffuse term), row-major, top row
// first, and NO_INSTANCE where nothing is hit.
export function rasterize(meshes, draws, matrices, width, height) {
  const pixels = width * height;
  const positions = new Float32Array(4 * pixels);
  const normals = new Float32Array(4 * pixels);
  const ids = new Uint32Array(pixels).fill(NO_INSTANCE);
  const depth = new Float32Array(pixels).fill(Infinity);
  const out = { width, height, positions, normals, ids };
  for (const draw of draws) {
    const mesh = meshes[draw.mesh];
    const verts = transformVertices(mesh, draw, matrices.viewProj);
    const idx = mesh.indices;
    for (let t = 0; t < idx.length; t += 3) {
      const tri = [verts[idx[t]], verts[idx[t + 1]], verts[idx[t + 2]]];
      // The face normals by the triangle's winding, as psao-eval's G-buffer
      // takes them: world space for the facing test, mesh space in case a
      // vertex normal is zero.
      const face = cross(sub(tri[1].world, tri[0].world), sub(tri[2].world, tri[0].world));
      const faceLocal = cross(sub(tri[1].local, tri[0].local), sub(tri[2].local, tri[0].local));
      const polygon = clipNear(tri);
      for (let k = 1; k + 1 < polygon.length; k++) {
        fill([polygon[0], polygon[k], polygon[k + 1]], { face, faceLocal, draw, matrices, out, depth });
      }
    }
  }
  return out;
}

// Per vertex: clip-space position and the attributes to interpolate.
function transformVertices(mesh, draw, viewProj) {
  const { model: m, normal: nm } = draw;
  // The lookup uses the mesh's own vertices; the place on screen the posed
  // ones (a skinned or morphing node's, from pose.js; else the same).
  const p = mesh.positions;
  const n = mesh.normals;
  const pp = draw.posed?.positions ?? p;
  const pn = draw.posed?.normals ?? n;
  const verts = new Array(p.length / 3);
  for (let v = 0; v < verts.length; v++) {
    const [x, y, z] = [pp[3 * v], pp[3 * v + 1], pp[3 * v + 2]];
    const [a, b, c] = [pn[3 * v], pn[3 * v + 1], pn[3 * v + 2]];
    const world = [0, 1, 2].map((k) => m[k] * x + m[4 + k] * y + m[8 + k] * z + m[12 + k]);
    const clip = [0, 1, 2, 3].map((k) => viewProj[k] * world[0] + viewProj[4 + k] * world[1] + viewProj[8 + k] * world[2] + viewProj[12 + k]);
    verts[v] = {
      clip,
      world,
      worldNormal: [0, 1, 2].map((k) => nm[k] * a + nm[4 + k] * b + nm[8 + k] * c),
      local: [p[3 * v], p[3 * v + 1], p[3 * v + 2]],
      localNormal: [n[3 * v], n[3 * v + 1], n[3 * v + 2]],
    };
  }
  return verts;
}

const ATTRIBUTES = ["world", "worldNormal", "local", "localNormal"];

// Sutherland-Hodgman against the near plane (clip z >= 0 in WebGPU's clip
// space); attributes are linear in clip space, so they are lerped as is.
function clipNear(tri) {
  const out = [];
  for (let i = 0; i < 3; i++) {
    const a = tri[i];
    const b = tri[(i + 1) % 3];
    const da = a.clip[2];
    const db = b.clip[2];
    if (da >= 0) out.push(a);
    if (da >= 0 !== db >= 0) {
      const s = da / (da - db);
      const lerp = (u, v) => u.map((x, k) => x + (v[k] - x) * s);
      const v = { clip: lerp(a.clip, b.clip) };
      for (const name of ATTRIBUTES) v[name] = lerp(a[name], b[name]);
      out.push(v);
    }
  }
  return out;
}

// Rasterizes one clipped triangle into the G-buffer.
function fill(tri, { face, faceLocal, draw, matrices, out, depth }) {
  const { width, height, positions, normals, ids } = out;
  // Screen positions (pixels, y down), depth z/w and 1/w.
  const s = tri.map((v) => {
    const iw = 1 / v.clip[3];
    return [(v.clip[0] * iw * 0.5 + 0.5) * width, (0.5 - v.clip[1] * iw * 0.5) * height, v.clip[2] * iw, iw];
  });
  const area = (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[1][1] - s[0][1]) * (s[2][0] - s[0][0]);
  if (!(Math.abs(area) > 0)) return;
  const x0 = Math.max(0, Math.floor(Math.min(s[0][0], s[1][0], s[2][0])));
  const x1 = Math.min(width - 1, Math.ceil(Math.max(s[0][0], s[1][0], s[2][0])));
  const y0 = Math.max(0, Math.floor(Math.min(s[0][1], s[1][1], s[2][1])));
  const y1 = Math.min(height - 1, Math.ceil(Math.max(s[0][1], s[1][1], s[2][1])));
  const edge = (a, b, x, y) => ((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])) / area;
  for (let y = y0; y <= y1; y++) {
    for (let x = x0; x <= x1; x++) {
      const cx = x + 0.5;
      const cy = y + 0.5;
      // Screen-space barycentrics: each is positive inside, whatever the winding.
      const b0 = edge(s[1], s[2], cx, cy);
      const b1 = edge(s[2], s[0], cx, cy);
      const b2 = 1 - b0 - b1;
      if (b0 < 0 || b1 < 0 || b2 < 0) continue;
      const z = b0 * s[0][2] + b1 * s[1][2] + b2 * s[2][2];
      const i = y * width + x;
      if (!(z >= 0 && z <= 1 && z < depth[i])) continue;
      depth[i] = z;
      // Perspective-correct weights.
      const w0 = b0 * s[0][3];
      const w1 = b1 * s[1][3];
      const w2 = b2 * s[2][3];
      const sum = w0 + w1 + w2;
      const at = (name) => [0, 1, 2].map((k) => (w0 * tri[0][name][k] + w1 * tri[1][name][k] + w2 * tri[2][name][k]) / sum);
      const world = at("world");
      let n = normalize(at("worldNormal"));
      if (dot(n, n) === 0) n = normalize(face);
      let nLocal = normalize(at("localNormal"));
      if (dot(nLocal, nLocal) === 0) nLocal = normalize(faceLocal);
      // As psao-eval's G-buffer for a double-sided face: flip the normals
      // when the face, turned to agree with the vertex normal, faces away
      // from the camera.
      const towards = dot(face, n) < 0 ? -1 : 1;
      if (towards * dot(face, sub(world, matrices.eye)) > 0) {
        n = n.map((c) => -c);
        nLocal = nLocal.map((c) => -c);
      }
      const [p, q] = draw.bindSpace ? [at("local"), nLocal] : [world, n];
      positions.set([p[0], p[1], p[2], 1], 4 * i);
      normals.set([q[0], q[1], q[2], Math.max(dot(n, matrices.light), 0)], 4 * i);
      ids[i] = draw.instance;
    }
  }
}
