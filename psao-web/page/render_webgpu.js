// The WebGPU renderer: per frame, three passes in one submission.
//  1. G-buffer (gbuffer.wgsl): the scene's meshes into lookup position
//     (rgba32float), lookup normal + diffuse term (rgba32float), instance
//     id (r32uint, 0xFFFFFFFF where nothing is hit) and depth.
//  2. AO (the project's reconstruct.wgsl + ao_pass.wgsl): psao_ao per
//     pixel from the mirror's buffers, into a storage buffer.
//  3. Display (display.wgsl): the lit and AO views side by side.

const GBUFFER_POSITION = "rgba32float";
const GBUFFER_NORMAL = "rgba32float";
const GBUFFER_INSTANCE = "r32uint";
const DEPTH = "depth32float";
const NO_INSTANCE = 0xffffffff;
const DRAW_BYTES = 144; // struct Draw of gbuffer.wgsl: 2 mat4x4 + vec4<u32>
const INSTANCE_BYTES = 48 * 4; // struct PsaoInstance of reconstruct.wgsl

// Makes the renderer, or returns null when the browser has no usable WebGPU
// adapter (the page then falls back to the CPU). `scene` is parseGlb's.
export async function createWebGpuRenderer(canvas, scene, normalTable) {
  if (!navigator.gpu) return null;
  // (Chromium without a usable backend throws here rather than answering null.)
  const adapter = await navigator.gpu.requestAdapter().catch(() => null);
  if (!adapter) return null;
  // The mirror's arrays can be large: ask for what the adapter allows. The
  // G-buffer's targets take 36 bytes per pixel, above WebGPU's default
  // limit of 32 (adapters commonly allow 64 or 128; where one does not,
  // the pipeline fails and the page falls back to the CPU).
  const device = await adapter.requestDevice({
    requiredLimits: {
      maxStorageBufferBindingSize: adapter.limits.maxStorageBufferBindingSize,
      maxBufferSize: adapter.limits.maxBufferSize,
      maxColorAttachmentBytesPerSample: adapter.limits.maxColorAttachmentBytesPerSample,
    },
  });
  const [gbuffer, reconstruct, aoPass, display] = await Promise.all(
    ["/gbuffer.wgsl", "/reconstruct.wgsl", "/ao_pass.wgsl", "/display.wgsl"].map(fetchText),
  );
  const renderer = new WebGpuRenderer(adapter, device, canvas, scene);
  await renderer.init({ gbuffer, ao: reconstruct + "\n" + aoPass, display }, normalTable);
  return renderer;
}

class WebGpuRenderer {
  constructor(adapter, device, canvas, scene) {
    this.mode = "WebGPU";
    this.gpuMirror = true; // main.js uploads the mirror's arrays (uploadMirror)
    this.adapterInfo = adapter.info ? `${adapter.info.vendor} ${adapter.info.architecture} ${adapter.info.description}`.trim() : "";
    this.device = device;
    this.canvas = canvas;
    this.errors = []; // the first few WebGPU errors (one per frame would repeat)
    const report = (message) => this.errors.length < 10 && this.errors.push(message);
    device.addEventListener("uncapturederror", (e) => report(`WebGPU: ${e.error.message}`));
    device.lost.then((info) => report(`WebGPU device lost: ${info.message}`));
    this.context = canvas.getContext("webgpu");
    this.format = navigator.gpu.getPreferredCanvasFormat();
    this.context.configure({ device, format: this.format, alphaMode: "opaque" });
    this.meshes = scene.meshes.map((m) => ({
      positions: this.bufferWith(m.positions, GPUBufferUsage.VERTEX),
      normals: this.bufferWith(m.normals, GPUBufferUsage.VERTEX),
      indices: this.bufferWith(m.indices, GPUBufferUsage.INDEX),
      count: m.indices.length,
    }));
    this.cameraBuffer = device.createBuffer({ size: 96, usage: GPUBufferUsage.UNIFORM | GPUBufferUsage.COPY_DST });
    this.drawBuffer = null;
    this.mirror = { instances: null, buckets: null, words: null }; // GPUBuffer + bytes bound
    this.size = null; // [width, height] of each view (the G-buffer)
  }

  async init(code, normalTable) {
    const d = this.device;
    const [gbufferModule, aoModule, displayModule] = await Promise.all([
      compile(d, "gbuffer.wgsl", code.gbuffer),
      compile(d, "reconstruct.wgsl + ao_pass.wgsl", code.ao),
      compile(d, "display.wgsl", code.display),
    ]);
    const attribute = (location) => ({ arrayStride: 12, attributes: [{ shaderLocation: location, offset: 0, format: "float32x3" }] });
    [this.gbufferPipeline, this.aoPipeline, this.displayPipeline] = await Promise.all([
      d.createRenderPipelineAsync({
        layout: "auto",
        // 0, 1: the bind-pose position and normal (the lookup of a
        // bind-space instance); 2, 3: the drawn ones (the same buffers but
        // for a skinned or morphing node, posed by pose.js).
        vertex: { module: gbufferModule, entryPoint: "vs", buffers: [attribute(0), attribute(1), attribute(2), attribute(3)] },
        fragment: {
          module: gbufferModule,
          entryPoint: "fs",
          targets: [{ format: GBUFFER_POSITION }, { format: GBUFFER_NORMAL }, { format: GBUFFER_INSTANCE }],
        },
        primitive: { topology: "triangle-list", cullMode: "none" },
        depthStencil: { format: DEPTH, depthWriteEnabled: true, depthCompare: "less" },
      }),
      d.createComputePipelineAsync({ layout: "auto", compute: { module: aoModule, entryPoint: "reconstruct_gbuffer" } }),
      d.createRenderPipelineAsync({
        layout: "auto",
        vertex: { module: displayModule, entryPoint: "vs" },
        fragment: { module: displayModule, entryPoint: "fs", targets: [{ format: this.format }] },
      }),
    ]);
    this.normalTable = this.bufferWith(normalTable, GPUBufferUsage.STORAGE);
    // An empty mirror until the first keyframe: one zeroed PsaoInstance
    // (not sampleable: AO 1) and a word each, as storage buffers cannot be
    // empty.
    this.uploadMirror(new Uint32Array(0), new Uint32Array(0), new Uint32Array(0));
  }

  // A buffer holding `data` (a typed array), padded to 16 bytes at least.
  bufferWith(data, usage) {
    const buffer = this.device.createBuffer({ size: Math.max(16, align(data.byteLength, 4)), usage: usage | GPUBufferUsage.COPY_DST });
    this.device.queue.writeBuffer(buffer, 0, data);
    return buffer;
  }

  // Uploads the mirror's flat arrays (WasmSession's gpu_instances,
  // gpu_buckets, gpu_words). Buffers grow (never shrink) and are bound
  // with exactly the bytes of the data, so arrayLength(&psao_instances) is
  // the mirror's instance count; the bind group is made again when a
  // binding's size changes.
  uploadMirror(instances, buckets, words) {
    const parts = {
      instances: instances.length ? instances : new Uint32Array(INSTANCE_BYTES / 4),
      buckets: buckets.length ? buckets : new Uint32Array(2),
      words: words.length ? words : new Uint32Array(1),
    };
    let rebind = !this.mirrorGroup;
    for (const [name, data] of Object.entries(parts)) {
      const slot = this.mirror[name];
      if (!slot || slot.buffer.size < data.byteLength) {
        slot?.buffer.destroy();
        const size = align(Math.max(data.byteLength * 1.25, 256), 4);
        this.mirror[name] = { buffer: this.device.createBuffer({ size, usage: GPUBufferUsage.STORAGE | GPUBufferUsage.COPY_DST }), bytes: -1 };
      }
      const now = this.mirror[name];
      this.device.queue.writeBuffer(now.buffer, 0, data);
      if (now.bytes !== data.byteLength) rebind = true;
      now.bytes = data.byteLength;
    }
    if (rebind) {
      const bind = (binding, buffer, size) => ({ binding, resource: { buffer, size } });
      this.mirrorGroup = this.device.createBindGroup({
        layout: this.aoPipeline.getBindGroupLayout(0),
        entries: [
          bind(0, this.mirror.instances.buffer, this.mirror.instances.bytes),
          bind(1, this.mirror.buckets.buffer, this.mirror.buckets.bytes),
          bind(2, this.mirror.words.buffer, this.mirror.words.bytes),
          bind(3, this.normalTable, 256 * 16),
        ],
      });
    }
  }

  // Sets the size of each view (the G-buffer); the canvas holds two.
  resize(width, height) {
    if (this.size && this.size[0] === width && this.size[1] === height) return;
    this.size = [width, height];
    this.canvas.width = 2 * width;
    this.canvas.height = height;
    for (const t of [this.positionTex, this.normalTex, this.instanceTex, this.depthTex]) t?.destroy();
    this.aoBuffer?.destroy();
    const d = this.device;
    const target = (format) => d.createTexture({
      size: [width, height],
      format,
      usage: GPUTextureUsage.RENDER_ATTACHMENT | GPUTextureUsage.TEXTURE_BINDING | GPUTextureUsage.COPY_SRC,
    });
    this.positionTex = target(GBUFFER_POSITION);
    this.normalTex = target(GBUFFER_NORMAL);
    this.instanceTex = target(GBUFFER_INSTANCE);
    this.depthTex = d.createTexture({ size: [width, height], format: DEPTH, usage: GPUTextureUsage.RENDER_ATTACHMENT });
    this.aoBuffer = d.createBuffer({ size: width * height * 4, usage: GPUBufferUsage.STORAGE | GPUBufferUsage.COPY_SRC });
    this.aoGroup = d.createBindGroup({
      layout: this.aoPipeline.getBindGroupLayout(1),
      entries: [
        { binding: 0, resource: this.positionTex.createView() },
        { binding: 1, resource: this.normalTex.createView() },
        { binding: 2, resource: this.instanceTex.createView() },
        { binding: 3, resource: { buffer: this.aoBuffer } },
      ],
    });
    this.displayGroup = d.createBindGroup({
      layout: this.displayPipeline.getBindGroupLayout(0),
      entries: [
        { binding: 0, resource: this.normalTex.createView() },
        { binding: 1, resource: this.instanceTex.createView() },
        { binding: 2, resource: { buffer: this.aoBuffer } },
      ],
    });
  }

  // Writes the camera and the draws (the nodes, with their current model
  // matrices) for the next render.
  setFrame(matrices, draws) {
    const camera = new Float32Array(24);
    camera.set(matrices.viewProj, 0);
    camera.set(matrices.eye, 16);
    camera.set(matrices.light, 20);
    this.device.queue.writeBuffer(this.cameraBuffer, 0, camera);
    const bytes = Math.max(draws.length, 1) * DRAW_BYTES;
    if (!this.drawBuffer || this.drawBuffer.size < bytes) {
      this.drawBuffer?.destroy();
      this.drawBuffer = this.device.createBuffer({ size: bytes, usage: GPUBufferUsage.STORAGE | GPUBufferUsage.COPY_DST });
      this.gbufferGroup = this.device.createBindGroup({
        layout: this.gbufferPipeline.getBindGroupLayout(0),
        entries: [
          { binding: 0, resource: { buffer: this.cameraBuffer } },
          { binding: 1, resource: { buffer: this.drawBuffer } },
        ],
      });
    }
    // A skinned node's posed vertices, in buffers of its own.
    this.posed ??= new Map();
    for (const draw of draws) {
      if (!draw.posed) continue;
      let b = this.posed.get(draw.node);
      if (!b) {
        const size = draw.posed.positions.byteLength;
        const make = () => this.device.createBuffer({ size, usage: GPUBufferUsage.VERTEX | GPUBufferUsage.COPY_DST });
        b = { positions: make(), normals: make() };
        this.posed.set(draw.node, b);
      }
      this.device.queue.writeBuffer(b.positions, 0, draw.posed.positions);
      this.device.queue.writeBuffer(b.normals, 0, draw.posed.normals);
    }
    const data = new ArrayBuffer(bytes);
    draws.forEach((draw, i) => {
      new Float32Array(data, i * DRAW_BYTES, 32).set([...draw.model, ...draw.normal]);
      new Uint32Array(data, i * DRAW_BYTES + 128, 4).set([draw.instance, draw.bindSpace ? 1 : 0, 0, 0]);
    });
    this.device.queue.writeBuffer(this.drawBuffer, 0, data);
    this.draws = draws;
  }

  // Renders the frame set by setFrame; resolves when the GPU is done.
  async render() {
    const d = this.device;
    const [width, height] = this.size;
    const encoder = d.createCommandEncoder();
    const attach = (texture, clearValue) => ({ view: texture.createView(), loadOp: "clear", storeOp: "store", clearValue });
    const gpass = encoder.beginRenderPass({
      colorAttachments: [
        attach(this.positionTex, [0, 0, 0, 0]),
        attach(this.normalTex, [0, 0, 0, 0]),
        attach(this.instanceTex, [NO_INSTANCE, 0, 0, 0]),
      ],
      depthStencilAttachment: { view: this.depthTex.createView(), depthLoadOp: "clear", depthStoreOp: "discard", depthClearValue: 1 },
    });
    gpass.setPipeline(this.gbufferPipeline);
    gpass.setBindGroup(0, this.gbufferGroup);
    this.draws.forEach((draw, i) => {
      const mesh = this.meshes[draw.mesh];
      const posed = draw.posed ? this.posed.get(draw.node) : mesh;
      gpass.setVertexBuffer(0, mesh.positions);
      gpass.setVertexBuffer(1, mesh.normals);
      gpass.setVertexBuffer(2, posed.positions);
      gpass.setVertexBuffer(3, posed.normals);
      gpass.setIndexBuffer(mesh.indices, "uint32");
      gpass.drawIndexed(mesh.count, 1, 0, 0, i); // firstInstance = draw index
    });
    gpass.end();

    const cpass = encoder.beginComputePass();
    cpass.setPipeline(this.aoPipeline);
    cpass.setBindGroup(0, this.mirrorGroup);
    cpass.setBindGroup(1, this.aoGroup);
    cpass.dispatchWorkgroups(Math.ceil(width / 8), Math.ceil(height / 8));
    cpass.end();

    const dpass = encoder.beginRenderPass({ colorAttachments: [attach(this.context.getCurrentTexture(), [0, 0, 0, 1])] });
    dpass.setPipeline(this.displayPipeline);
    dpass.setBindGroup(0, this.displayGroup);
    dpass.draw(3);
    dpass.end();
    d.queue.submit([encoder.finish()]);
    await d.queue.onSubmittedWorkDone();
  }

  // Reads back the last render's G-buffer and AO: 4 floats per pixel of
  // position and normal (xyz: the lookup vectors; normal.w: the diffuse
  // term), one instance id and one AO value per pixel, row-major.
  async readback() {
    const [width, height] = this.size;
    const [positions, normals, ids, ao] = await Promise.all([
      this.readTexture(this.positionTex, 16).then((b) => new Float32Array(b)),
      this.readTexture(this.normalTex, 16).then((b) => new Float32Array(b)),
      this.readTexture(this.instanceTex, 4).then((b) => new Uint32Array(b)),
      this.readBuffer(this.aoBuffer).then((b) => new Float32Array(b)),
    ]);
    return { width, height, positions, normals, ids, ao };
  }

  // A texture's texels, tightly packed (copies need rows of 256 bytes).
  async readTexture(texture, texelBytes) {
    const [width, height] = this.size;
    const row = width * texelBytes;
    const paddedRow = align(row, 256);
    const staging = this.device.createBuffer({ size: paddedRow * height, usage: GPUBufferUsage.COPY_DST | GPUBufferUsage.MAP_READ });
    const encoder = this.device.createCommandEncoder();
    encoder.copyTextureToBuffer({ texture }, { buffer: staging, bytesPerRow: paddedRow }, [width, height]);
    this.device.queue.submit([encoder.finish()]);
    await staging.mapAsync(GPUMapMode.READ);
    const padded = new Uint8Array(staging.getMappedRange());
    const out = new Uint8Array(row * height);
    for (let y = 0; y < height; y++) out.set(padded.subarray(y * paddedRow, y * paddedRow + row), y * row);
    staging.destroy();
    return out.buffer;
  }

  async readBuffer(buffer) {
    const staging = this.device.createBuffer({ size: buffer.size, usage: GPUBufferUsage.COPY_DST | GPUBufferUsage.MAP_READ });
    const encoder = this.device.createCommandEncoder();
    encoder.copyBufferToBuffer(buffer, 0, staging, 0, buffer.size);
    this.device.queue.submit([encoder.finish()]);
    await staging.mapAsync(GPUMapMode.READ);
    const out = staging.getMappedRange().slice(0);
    staging.destroy();
    return out;
  }
}

const align = (n, a) => Math.ceil(n / a) * a;

async function fetchText(url) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return response.text();
}

// A shader module, or an error listing the compiler's messages.
async function compile(device, name, code) {
  const module = device.createShaderModule({ label: name, code });
  const info = await module.getCompilationInfo();
  const errors = info.messages.filter((m) => m.type === "error");
  if (errors.length) throw new Error(`${name}: ${errors.map((m) => `${m.lineNum}:${m.linePos} ${m.message}`).join("; ")}`);
  return module;
}
