// A reader for the glTF 2.0 binary (GLB) that `psao serve --web` writes as
// /scene.glb, and for nothing more general: one buffer (the BIN chunk);
// meshes of one triangle primitive with POSITION and NORMAL (VEC3 float)
// and u32 indices, and for a skinned mesh JOINTS_0 (VEC4 u16) and
// WEIGHTS_0 (VEC4 float); a flat list of nodes, each with `mesh`, an
// optional column-major `matrix` (the instance's rest world transform) and
// `extras: {psao_instance, bind_space}`, and for a skinned instance
// `extras.psao_skin: {joints, fps, frames, duration, matrices}` (its joint
// matrices sampled over the animation loop: an accessor of frames * joints
// * 12 floats), for a morphing one `extras.psao_morph: {targets, fps,
// frames, duration, weights}` (frames * targets floats) over its mesh's
// `targets` (POSITION, NORMAL offsets) and rest `weights`; see pose.js. Anything else is refused with an error that
// says what, rather than drawn wrongly.

const MAGIC_GLTF = 0x46546c67; // "glTF", little-endian
const CHUNK_JSON = 0x4e4f534a; // "JSON"
const CHUNK_BIN = 0x004e4942; // "BIN\0"
const FLOAT = 5126;
const UNSIGNED_INT = 5125;
const UNSIGNED_SHORT = 5123;
const TRIANGLES = 4;
const COMPONENTS = { SCALAR: 1, VEC3: 3, VEC4: 4 };
const COMPONENT_BYTES = { [FLOAT]: 4, [UNSIGNED_INT]: 4, [UNSIGNED_SHORT]: 2 };

// Parses a GLB. Returns
//   { meshes: [{ positions: Float32Array, normals: Float32Array, indices: Uint32Array }],
//     nodes: [{ mesh, matrix: Float32Array(16), instance, bindSpace }] }
// with tightly packed copies of the vertex data (3 floats per vertex).
export function parseGlb(arrayBuffer) {
  const view = new DataView(arrayBuffer);
  if (view.byteLength < 20 || view.getUint32(0, true) !== MAGIC_GLTF) {
    throw new Error("scene.glb: not a GLB (no glTF magic)");
  }
  if (view.getUint32(4, true) !== 2) {
    throw new Error(`scene.glb: glTF version ${view.getUint32(4, true)}, expected 2`);
  }
  const total = Math.min(view.getUint32(8, true), view.byteLength);
  let json = null;
  let bin = null;
  for (let at = 12; at + 8 <= total; ) {
    const length = view.getUint32(at, true);
    const type = view.getUint32(at + 4, true);
    const start = at + 8;
    if (start + length > total) throw new Error("scene.glb: a chunk runs past the end");
    if (type === CHUNK_JSON && json === null) {
      json = JSON.parse(new TextDecoder().decode(new Uint8Array(arrayBuffer, start, length)));
    } else if (type === CHUNK_BIN && bin === null) {
      bin = new DataView(arrayBuffer, start, length);
    } // Other chunk types are skipped, as glTF says.
    at = start + ((length + 3) & ~3);
  }
  if (json === null) throw new Error("scene.glb: no JSON chunk");

  const accessor = (index, componentType, type) => readAccessor(json, bin, index, componentType, type);
  const meshes = (json.meshes ?? []).map((mesh, m) => {
    if (mesh.primitives?.length !== 1) throw new Error(`scene.glb: mesh ${m} has ${mesh.primitives?.length ?? 0} primitives, expected 1`);
    const prim = mesh.primitives[0];
    if ((prim.mode ?? TRIANGLES) !== TRIANGLES) throw new Error(`scene.glb: mesh ${m} is not triangles`);
    const { POSITION, NORMAL } = prim.attributes ?? {};
    if (POSITION === undefined || NORMAL === undefined || prim.indices === undefined) {
      throw new Error(`scene.glb: mesh ${m} lacks POSITION, NORMAL or indices`);
    }
    const positions = accessor(POSITION, FLOAT, "VEC3");
    const normals = accessor(NORMAL, FLOAT, "VEC3");
    const indices = accessor(prim.indices, UNSIGNED_INT, "SCALAR");
    const vertices = positions.length / 3;
    if (normals.length !== positions.length) throw new Error(`scene.glb: mesh ${m} has ${normals.length / 3} normals for ${vertices} positions`);
    if (indices.length % 3 !== 0) throw new Error(`scene.glb: mesh ${m} has ${indices.length} indices, not a multiple of 3`);
    for (const i of indices) {
      if (i >= vertices) throw new Error(`scene.glb: mesh ${m} indexes vertex ${i} of ${vertices}`);
    }
    const out = { positions, normals, indices };
    if (prim.targets !== undefined) {
      if (!Array.isArray(prim.targets)) throw new Error(`scene.glb: mesh ${m}'s targets are not a list`);
      out.targets = prim.targets.map((t, k) => {
        const target = {};
        for (const [name, key] of [["POSITION", "positions"], ["NORMAL", "normals"]]) {
          if (t[name] === undefined) continue;
          target[key] = accessor(t[name], FLOAT, "VEC3");
          if (target[key].length !== positions.length) throw new Error(`scene.glb: mesh ${m}'s target ${k} ${name} is not one VEC3 per vertex`);
        }
        return target;
      });
      out.restWeights = Float32Array.from(mesh.weights ?? out.targets.map(() => 0));
      if (out.restWeights.length !== out.targets.length) throw new Error(`scene.glb: mesh ${m} has ${out.restWeights.length} weights for ${out.targets.length} targets`);
    }
    const { JOINTS_0, WEIGHTS_0 } = prim.attributes;
    if ((JOINTS_0 === undefined) !== (WEIGHTS_0 === undefined)) throw new Error(`scene.glb: mesh ${m} has one of JOINTS_0 and WEIGHTS_0`);
    if (JOINTS_0 !== undefined) {
      out.joints = accessor(JOINTS_0, UNSIGNED_SHORT, "VEC4");
      out.weights = accessor(WEIGHTS_0, FLOAT, "VEC4");
      if (out.joints.length !== 4 * vertices || out.weights.length !== 4 * vertices) {
        throw new Error(`scene.glb: mesh ${m}'s joints or weights are not one VEC4 per vertex`);
      }
    }
    return out;
  });

  const nodes = (json.nodes ?? []).map((node, n) => {
    if (node.mesh === undefined) return null; // nothing to draw
    if (!(node.mesh >= 0 && node.mesh < meshes.length)) throw new Error(`scene.glb: node ${n} names mesh ${node.mesh}`);
    if (node.translation || node.rotation || node.scale) throw new Error(`scene.glb: node ${n} has TRS, expected a matrix`);
    if (node.children?.length) throw new Error(`scene.glb: node ${n} has children, expected a flat list`);
    const matrix = new Float32Array(node.matrix ?? [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    if (matrix.length !== 16) throw new Error(`scene.glb: node ${n}'s matrix has ${matrix.length} numbers`);
    const instance = node.extras?.psao_instance;
    if (!Number.isInteger(instance) || instance < 0 || instance > 0xfffffffe) {
      throw new Error(`scene.glb: node ${n} has no extras.psao_instance (a u32)`);
    }
    const out = { mesh: node.mesh, matrix, instance, bindSpace: node.extras.bind_space === true };
    const skin = node.extras.psao_skin;
    if (skin !== undefined) {
      const { joints, fps, frames, duration } = skin;
      if (!meshes[node.mesh].joints) throw new Error(`scene.glb: node ${n} is skinned but mesh ${node.mesh} has no JOINTS_0`);
      if (!(Number.isInteger(joints) && joints > 0 && Number.isInteger(frames) && frames > 0 && fps > 0 && duration >= 0)) {
        throw new Error(`scene.glb: node ${n}'s psao_skin is malformed`);
      }
      const matrices = accessor(skin.matrices, FLOAT, "SCALAR");
      if (matrices.length !== frames * joints * 12) throw new Error(`scene.glb: node ${n}'s psao_skin has ${matrices.length} floats, expected ${frames * joints * 12}`);
      out.skin = { joints, fps, frames, duration, matrices };
    }
    const morph = node.extras.psao_morph;
    if (morph !== undefined) {
      const { targets, fps, frames, duration } = morph;
      if (meshes[node.mesh].targets?.length !== targets) throw new Error(`scene.glb: node ${n}'s psao_morph names ${targets} targets its mesh lacks`);
      if (!(Number.isInteger(frames) && frames > 0 && fps > 0 && duration >= 0)) throw new Error(`scene.glb: node ${n}'s psao_morph is malformed`);
      const weights = accessor(morph.weights, FLOAT, "SCALAR");
      if (weights.length !== frames * targets) throw new Error(`scene.glb: node ${n}'s psao_morph has ${weights.length} weights, expected ${frames * targets}`);
      out.morph = { targets, fps, frames, duration, weights };
    }
    return out;
  });
  return { meshes, nodes: nodes.filter((n) => n !== null) };
}

// Copies accessor `index` (of the given componentType and type, both
// required) out of the BIN chunk into a tight Float32Array or Uint32Array,
// honouring accessor.byteOffset, bufferView.byteOffset and byteStride.
function readAccessor(json, bin, index, componentType, type) {
  const acc = json.accessors?.[index];
  if (!acc) throw new Error(`scene.glb: no accessor ${index}`);
  if (acc.componentType !== componentType || acc.type !== type) {
    throw new Error(`scene.glb: accessor ${index} is ${acc.type}/${acc.componentType}, expected ${type}/${componentType}`);
  }
  if (acc.sparse) throw new Error(`scene.glb: accessor ${index} is sparse`);
  const bv = json.bufferViews?.[acc.bufferView];
  if (!bv || (bv.buffer ?? 0) !== 0 || bin === null) throw new Error(`scene.glb: accessor ${index} has no data in the BIN chunk`);
  const comps = COMPONENTS[type];
  const elementBytes = COMPONENT_BYTES[componentType] * comps;
  const stride = bv.byteStride ?? elementBytes;
  const start = (bv.byteOffset ?? 0) + (acc.byteOffset ?? 0);
  const count = acc.count;
  const lastEnd = count === 0 ? start : start + (count - 1) * stride + elementBytes;
  if (stride < elementBytes || lastEnd > (bv.byteOffset ?? 0) + bv.byteLength || lastEnd > bin.byteLength) {
    throw new Error(`scene.glb: accessor ${index} runs past its bufferView`);
  }
  const size = COMPONENT_BYTES[componentType];
  const out = componentType === FLOAT ? new Float32Array(count * comps) : new Uint32Array(count * comps);
  const read =
    componentType === FLOAT ? (at) => bin.getFloat32(at, true) : componentType === UNSIGNED_SHORT ? (at) => bin.getUint16(at, true) : (at) => bin.getUint32(at, true);
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < comps; c++) out[i * comps + c] = read(start + i * stride + size * c);
  }
  return out;
}
