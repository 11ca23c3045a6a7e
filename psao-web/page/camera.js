// The viewer's camera: config.json's pose, optionally orbited with the
// mouse (drag: orbit about the target; wheel: distance). `?view=fixed`
// leaves it exactly as configured.

import { add, cross, dot, length, lookAt, multiply, normalize, perspective, scale, sub } from "./math.js";

export class Camera {
  // `config` is config.json's camera ({eye, target, up, fov_y}); `bounds`
  // the scene's bounding sphere ({center, radius}), for the depth range.
  constructor(config, bounds) {
    this.eye = [...config.eye];
    this.target = [...config.target];
    this.up = [...config.up];
    this.fovY = config.fov_y;
    this.bounds = bounds;
    this.version = 0; // bumped on every change, so renderers know to redraw
  }

  // View, projection and their product for an aspect ratio (width / height),
  // with the light direction the lit view uses (from over the camera's
  // shoulder, in world space).
  matrices(aspect) {
    const view = lookAt(this.eye, this.target, this.up);
    // Depth range: everything within twice the scene's radius of its centre
    // (instances move), and at least 1/2000 of far for the near plane.
    const far = length(sub(this.eye, this.bounds.center)) + 2 * this.bounds.radius;
    const proj = perspective(this.fovY, aspect, far / 2000, far);
    const light = normalize(add(normalize(sub(this.eye, this.target)), normalize(this.up)));
    return { view, proj, viewProj: multiply(proj, view), eye: this.eye, light };
  }

  // Mouse orbiting on `element`.
  attachOrbit(element) {
    let last = null;
    element.addEventListener("pointerdown", (e) => {
      last = [e.clientX, e.clientY];
      element.setPointerCapture(e.pointerId);
    });
    element.addEventListener("pointerup", () => (last = null));
    element.addEventListener("pointermove", (e) => {
      if (!last) return;
      this.orbit((e.clientX - last[0]) * -0.01, (e.clientY - last[1]) * -0.01);
      last = [e.clientX, e.clientY];
    });
    element.addEventListener("wheel", (e) => {
      e.preventDefault();
      const offset = sub(this.eye, this.target);
      this.eye = add(this.target, scale(offset, Math.exp(e.deltaY * 0.001)));
      this.version++;
    }, { passive: false });
  }

  // Turns the eye about the target: `yaw` about `up`, `pitch` towards it,
  // stopping short of the poles.
  orbit(yaw, pitch) {
    const up = normalize(this.up);
    const offset = sub(this.eye, this.target);
    const r = length(offset);
    const height = dot(offset, up);
    let elevation = Math.asin(Math.max(-1, Math.min(1, height / r)));
    // An orthonormal frame (side, fwd) around up, fwd along the current offset.
    const flat = normalize(sub(offset, scale(up, height)));
    const side = normalize(cross(up, flat));
    const dir = add(scale(flat, Math.cos(yaw)), scale(side, Math.sin(yaw)));
    elevation = Math.max(-1.5, Math.min(1.5, elevation + pitch));
    this.eye = add(this.target, scale(add(scale(dir, Math.cos(elevation)), scale(up, Math.sin(elevation))), r));
    this.version++;
  }
}

// The bounding sphere (centre of the box, half its diagonal) of the scene's
// nodes at their rest transforms.
export function sceneBounds(scene) {
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (const node of scene.nodes) {
    const m = node.matrix;
    const p = scene.meshes[node.mesh].positions;
    for (let v = 0; v < p.length; v += 3) {
      for (let k = 0; k < 3; k++) {
        const w = m[k] * p[v] + m[4 + k] * p[v + 1] + m[8 + k] * p[v + 2] + m[12 + k];
        lo[k] = Math.min(lo[k], w);
        hi[k] = Math.max(hi[k], w);
      }
    }
  }
  if (!(lo[0] <= hi[0])) return { center: [0, 0, 0], radius: 1 };
  const center = scale(add(lo, hi), 0.5);
  return { center, radius: Math.max(length(sub(hi, lo)) / 2, 1e-3) };
}
