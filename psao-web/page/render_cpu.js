// The CPU fallback renderer, for browsers without WebGPU (or `?cpu=1`):
// the G-buffer from raster.js, AO from the wasm's reconstruction (the same
// Rust code as the native client), both views drawn into a 2D canvas. Same
// interface as render_webgpu.js, less uploadMirror: the wasm reconstructs
// from the session's own mirror.

import { rasterize } from "./raster.js";

// As display.wgsl.
const BACKGROUND = [0.16, 0.18, 0.22];
const DIFFUSE = 0.75;
const AMBIENT = 0.25;

export class CpuRenderer {
  constructor(canvas, scene, session, mode) {
    this.mode = mode;
    this.canvas = canvas;
    this.meshes = scene.meshes;
    this.session = session;
    this.errors = [];
    this.context = canvas.getContext("2d");
    this.size = null;
    this.last = null; // the last render's G-buffer and AO
  }

  resize(width, height) {
    if (this.size && this.size[0] === width && this.size[1] === height) return;
    this.size = [width, height];
    this.canvas.width = 2 * width;
    this.canvas.height = height;
    this.image = this.context.createImageData(2 * width, height);
  }

  setFrame(matrices, draws) {
    this.matrices = matrices;
    this.draws = draws;
  }

  async render() {
    const [width, height] = this.size;
    const g = rasterize(this.meshes, this.draws, this.matrices, width, height);
    g.ao = this.session.reconstruct(g.positions, g.normals, g.ids);
    const px = this.image.data;
    for (let y = 0; y < height; y++) {
      for (let x = 0; x < width; x++) {
        const i = y * width + x;
        const hit = g.ids[i] !== 0xffffffff;
        const a = g.ao[i];
        const lit = (DIFFUSE * g.normals[4 * i + 3] + AMBIENT) * a;
        put(px, 2 * width * y + x, hit ? [lit, lit, lit] : BACKGROUND);
        put(px, 2 * width * y + width + x, hit ? [a, a, a] : BACKGROUND);
      }
    }
    this.context.putImageData(this.image, 0, 0);
    this.last = g;
  }

  async readback() {
    return this.last;
  }
}

function put(data, pixel, rgb) {
  data[4 * pixel] = rgb[0] * 255;
  data[4 * pixel + 1] = rgb[1] * 255;
  data[4 * pixel + 2] = rgb[2] * 255;
  data[4 * pixel + 3] = 255;
}
