// Deforming instances, posed as the server poses them: scene.glb carries,
// per morphing node, its morph weights and, per skinned node, its joint
// matrices (instance-local, as psao-scene's Pose::weights and
// Pose::joints), sampled over the scene's animation loop, with the mesh's
// morph targets and JOINTS_0/WEIGHTS_0. At scene time t the page blends
// the two samples around t, morphs the mesh as stored (each target's
// offsets times its weight less its rest weight; normals renormalized, as
// MorphTargets::apply), then skins the result (linear blend skinning, as
// SkinWeights::blend: weights normalized, a vertex without weight stays
// put; normals through the cofactor of the blended matrix, renormalized).
// The draw places the posed vertices with the stream's Transform of the
// instance; the lookup keeps the mesh's own position and normal
// (spec/wire-format.md 6.1).

// One node's deformation: `skin` { joints, fps, frames, duration, matrices }
// (matrices: frames * joints * 12 floats, columns x, y, z, translation)
// and/or `morph` { targets, fps, frames, duration, weights } (frames *
// targets floats), over `mesh` (with `targets` [{positions, normals}] and
// `restWeights` when it morphs).
export class NodePose {
  constructor(skin, morph, mesh) {
    this.skin = skin ?? null;
    this.morph = morph ?? null;
    this.mesh = mesh;
    const n = mesh.positions.length;
    this.positions = new Float32Array(n);
    this.normals = new Float32Array(n);
    this.morphed = { positions: new Float32Array(n), normals: new Float32Array(n) };
    this.blend = new Float32Array(12 * (skin?.joints ?? 0));
    this.weightsNow = new Float32Array(morph?.targets ?? 0);
  }

  // The floats of sample table `table` ({fps, frames, duration}, `per`
  // floats a sample) at scene time t, blended between the two samples
  // around it, into `out`.
  static sampleInto(table, values, per, t, out) {
    const { fps, frames, duration } = table;
    const u = duration > 0 ? (((t % duration) + duration) % duration) * fps : 0;
    const k = Math.min(Math.floor(u), frames - 1);
    const next = Math.min(k + 1, frames - 1);
    const f = Math.min(Math.max(u - k, 0), 1);
    const a = k * per;
    const b = next * per;
    for (let i = 0; i < per; i++) out[i] = values[a + i] * (1 - f) + values[b + i] * f;
  }

  // The posed positions and normals (instance-local) at scene time t.
  pose(t) {
    const base = this.morph ? this.applyMorph(t) : this.mesh;
    if (!this.skin) {
      this.positions.set(base.positions);
      this.normals.set(base.normals);
      return { positions: this.positions, normals: this.normals };
    }
    return this.applySkin(t, base);
  }

  // The mesh morphed to the weights at t.
  applyMorph(t) {
    const { targets } = this.morph;
    NodePose.sampleInto(this.morph, this.morph.weights, targets, t, this.weightsNow);
    const { positions, normals, targets: offsets, restWeights } = this.mesh;
    const p = this.morphed.positions;
    const n = this.morphed.normals;
    p.set(positions);
    n.set(normals);
    let turned = false;
    for (let k = 0; k < targets; k++) {
      const dw = this.weightsNow[k] - (restWeights[k] ?? 0);
      if (dw === 0 || !Number.isFinite(dw)) continue;
      const o = offsets[k];
      if (o.positions) for (let i = 0; i < p.length; i++) p[i] += dw * o.positions[i];
      if (o.normals) {
        turned = true;
        for (let i = 0; i < n.length; i++) n[i] += dw * o.normals[i];
      }
    }
    if (turned) {
      for (let v = 0; v < n.length; v += 3) {
        const len = Math.hypot(n[v], n[v + 1], n[v + 2]);
        if (len > 0 && Number.isFinite(len)) {
          n[v] /= len;
          n[v + 1] /= len;
          n[v + 2] /= len;
        } else {
          n[v] = normals[v];
          n[v + 1] = normals[v + 1];
          n[v + 2] = normals[v + 2];
        }
      }
    }
    return this.morphed;
  }

  // `base` skinned with the joint matrices at t.
  applySkin(t, base) {
    NodePose.sampleInto(this.skin, this.skin.matrices, this.skin.joints * 12, t, this.blend);
    const { positions, normals } = base;
    const { joints: jointIds, weights } = this.mesh;
    const J = this.skin.joints;
    const m = new Float32Array(12);
    for (let v = 0; v < positions.length / 3; v++) {
      m.fill(0);
      let sum = 0;
      for (let k = 0; k < 4; k++) {
        const w = weights[4 * v + k];
        const j = jointIds[4 * v + k];
        if (!(w > 0) || j >= J) continue;
        sum += w;
        for (let c = 0; c < 12; c++) m[c] += w * this.blend[12 * j + c];
      }
      const p = 3 * v;
      const [x, y, z] = [positions[p], positions[p + 1], positions[p + 2]];
      const [nx, ny, nz] = [normals[p], normals[p + 1], normals[p + 2]];
      if (!(sum > 0)) {
        this.positions.set([x, y, z], p);
        this.normals.set([nx, ny, nz], p);
        continue;
      }
      for (let c = 0; c < 12; c++) m[c] /= sum;
      this.positions[p] = m[0] * x + m[3] * y + m[6] * z + m[9];
      this.positions[p + 1] = m[1] * x + m[4] * y + m[7] * z + m[10];
      this.positions[p + 2] = m[2] * x + m[5] * y + m[8] * z + m[11];
      // The cofactor of the linear part (columns: y x z, z x x, x x y)
      // carries normals as the inverse transpose does, up to a scale.
      const cx = cross(m[3], m[4], m[5], m[6], m[7], m[8]);
      const cy = cross(m[6], m[7], m[8], m[0], m[1], m[2]);
      const cz = cross(m[0], m[1], m[2], m[3], m[4], m[5]);
      let ox = cx[0] * nx + cy[0] * ny + cz[0] * nz;
      let oy = cx[1] * nx + cy[1] * ny + cz[1] * nz;
      let oz = cx[2] * nx + cy[2] * ny + cz[2] * nz;
      const len = Math.hypot(ox, oy, oz) || 1;
      this.normals[p] = ox / len;
      this.normals[p + 1] = oy / len;
      this.normals[p + 2] = oz / len;
    }
    return { positions: this.positions, normals: this.normals };
  }
}

function cross(ax, ay, az, bx, by, bz) {
  return [ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx];
}
