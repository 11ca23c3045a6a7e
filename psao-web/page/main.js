// The psao browser client: joins the server's session over WebTransport,
// keeps the wasm mirror of its AO points, and draws the scene with AO
// rebuilt per pixel (WebGPU, else on the CPU). URL parameters:
//   ?view=fixed  config.json's camera exactly, and a fixed size (for tests)
//   ?cpu=1       the CPU fallback even where WebGPU works
// window.psaoTest holds the hooks tests/browser/drive.mjs uses.

import init, { WasmSession, SessionClose, normal_table } from "/pkg/psao_wasm.js";
import { Camera, sceneBounds } from "./camera.js";
import { parseGlb } from "./glb.js";
import { affineToMat4, normalMatrix } from "./math.js";
import { Overlay } from "./overlay.js";
import { CpuRenderer } from "./render_cpu.js";
import { createWebGpuRenderer } from "./render_webgpu.js";
import { SessionLink, plainStats } from "./session.js";
import { NodePose } from "./pose.js";

const params = new URLSearchParams(location.search);
const FIXED_VIEW = params.get("view") === "fixed";
const FORCE_CPU = params.get("cpu") === "1";
// Each view's size (the G-buffer's) with ?view=fixed; the CPU rasterizes at
// half of it and is shown scaled up.
const FIXED_SIZE = [640, 360];
const NO_INSTANCE = 0xffffffff;
const TOLERANCE = 1 / 255;

// Failures, shown in the overlay and state().error (the first few: a render
// that fails fails every frame).
const errors = [];
const report = (what, e) => errors.length < 10 && errors.push(`${what}: ${e?.stack ?? e}`);
addEventListener("error", (e) => report("error", e.message));
addEventListener("unhandledrejection", (e) => report("unhandled rejection", e.reason));

let canvas = document.getElementById("view");
const overlay = new Overlay(document.getElementById("overlay"));
let session = null; // WasmSession
let link = null; // SessionLink
let renderer = null; // WebGpuRenderer or CpuRenderer
let camera = null;
let scene = null;
// The server's scene time (config.json's scene_time) against this page's
// clock: performance.now() when it was read, at the request's midpoint.
let clock = { sceneTime: 0, at: 0 };

// Rendering state: one render at a time; a new one when the mirror, the
// camera or the size changed.
let inFlight = null;
let frozen = false;
let mirrorDirty = true;
let uploadedSequence;
let drawnKey = null;
let renders = 0;
let renderMs = null; // how long the last render took

const ready = start();
ready.catch((e) => report("start", e));

// Reconnecting: after the server ended the session for a reason a new
// session can mend (it shut down, was full, failed, or the connection was
// lost), the page joins again, with a fresh mirror and config.json read
// again (the server may be a new one, with a new certificate), waiting 1,
// 2, 4, 8 then 10 s between tries. A close for something the page did
// wrong (protocol_violation, message_too_large, ...) is left as it is.
const RECONNECT_CODES = new Set([0x06, 0x07, 0x08, 0x09]);
let reconnects = 0;
let reconnecting = false;
setInterval(() => {
  const closed = link?.closed;
  if (!closed || link.closing || reconnecting || frozen || !RECONNECT_CODES.has(closed.closeCode)) return;
  reconnecting = true;
  const wait = Math.min(10_000, 1000 * 2 ** Math.min(reconnects, 3));
  setTimeout(() => reconnect().finally(() => (reconnecting = false)), wait);
}, 250);

async function reconnect() {
  reconnects++;
  try {
    const asked = performance.now();
    const config = await fetchOk("/config.json").then((r) => r.json());
    const next = new WasmSession();
    const nextLink = new SessionLink(next, SessionClose, config);
    await nextLink.start();
    clock = { sceneTime: config.scene_time ?? 0, at: (asked + performance.now()) / 2 };
    session = next;
    link = nextLink;
    if (renderer instanceof CpuRenderer) renderer.session = next;
    mirrorDirty = true;
  } catch (e) {
    console.warn(`reconnect ${reconnects} failed: ${e?.message ?? e}`);
  }
}

async function start() {
  const asked = performance.now();
  const [config, glb] = await Promise.all([
    fetchOk("/config.json")
      .then((r) => r.json())
      .then((c) => {
        clock = { sceneTime: c.scene_time ?? 0, at: (asked + performance.now()) / 2 };
        return c;
      }),
    fetchOk("/scene.glb").then((r) => r.arrayBuffer()),
    init(),
  ]);
  scene = parseGlb(glb);
  for (const node of scene.nodes) {
    if (node.skin || node.morph) node.poseState = new NodePose(node.skin, node.morph, scene.meshes[node.mesh]);
  }
  camera = new Camera(config.camera, sceneBounds(scene));

  session = new WasmSession(); // queues HELLO
  link = new SessionLink(session, SessionClose, config);
  const connected = link.start();
  connected.catch(() => {}); // awaited below, after the renderer is made
  renderer = await makeRenderer();
  if (!FIXED_VIEW) camera.attachOrbit(canvas);
  requestAnimationFrame(tick); // the scene shows (with AO 1) before the first keyframe
  await connected;
  await link.welcomed;
}

async function fetchOk(url) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return response;
}

// WebGPU where it works, else the CPU fallback, saying why.
async function makeRenderer() {
  if (FORCE_CPU) return new CpuRenderer(canvas, scene, session, "CPU fallback (forced by ?cpu=1: reconstruction in wasm)");
  try {
    const gpu = await createWebGpuRenderer(canvas, scene, normal_table());
    if (gpu) return gpu;
    return new CpuRenderer(canvas, scene, session, "CPU fallback (no WebGPU: reconstruction in wasm)");
  } catch (e) {
    console.error("WebGPU failed, falling back to the CPU:", e);
    // The canvas may hold a WebGPU context now: draw on a fresh one.
    const fresh = document.createElement("canvas");
    fresh.id = canvas.id;
    canvas.replaceWith(fresh);
    canvas = fresh;
    return new CpuRenderer(canvas, scene, session, `CPU fallback (WebGPU failed: ${e?.message ?? e}; reconstruction in wasm)`);
  }
}

// Each view's size: fixed, or half the window's width at 16:9.
function viewSize() {
  let [w, h] = FIXED_SIZE;
  if (!FIXED_VIEW) {
    w = Math.max(160, Math.min(960, Math.floor((innerWidth - 24) / 2)));
    h = Math.round((w * 9) / 16);
  }
  canvas.style.width = `${2 * w}px`;
  canvas.style.height = `${h}px`;
  return renderer instanceof CpuRenderer ? [w >> 1, h >> 1] : [w, h];
}

// The server's scene time now, as this page's clock follows it.
function sceneTime() {
  return clock.sceneTime + (performance.now() - clock.at) / 1000;
}

// The draws: every node's mesh, placed by the stream's transform of its
// instance when it has one (else at rest); a skinned or morphing one
// posed at the server's scene time (pose.js), looked up by its bind pose.
function draws() {
  const t = sceneTime();
  return scene.nodes.map((node) => {
    const bindSpace = node.bindSpace || session.bind_space(node.instance);
    const placed = session.transform(node.instance);
    const model = placed ? affineToMat4(placed) : node.matrix;
    const posed = node.poseState?.pose(t);
    return { mesh: node.mesh, model, normal: normalMatrix(model), instance: node.instance, bindSpace, posed, node: scene.nodes.indexOf(node) };
  });
}

// Renders the current state: uploads the mirror if it changed, then the
// G-buffer, AO and display passes.
async function renderNow() {
  const sequence = session.sequence();
  if (renderer.gpuMirror && (mirrorDirty || sequence !== uploadedSequence)) {
    renderer.uploadMirror(session.gpu_instances(), session.gpu_buckets(), session.gpu_words());
  }
  mirrorDirty = false;
  uploadedSequence = sequence;
  const [w, h] = viewSize();
  renderer.resize(w, h);
  const started = performance.now();
  renderer.setFrame(camera.matrices(w / h), draws());
  await renderer.render();
  renderMs = performance.now() - started;
  renders++;
}

function tick() {
  requestAnimationFrame(tick);
  if (frozen || inFlight) return;
  if (session.take_changes().length) mirrorDirty = true;
  const key = `${session.sequence()}|${camera.version}|${viewSize()}`;
  if (!mirrorDirty && key === drawnKey) return;
  drawnKey = key;
  inFlight = renderNow()
    .catch((e) => report("render", e))
    .finally(() => (inFlight = null));
}

function state() {
  const s = {
    welcomed: false,
    in_sync: false,
    sequence: null,
    digest: null,
    stats: null,
    mode: renderer?.mode ?? "starting",
    adapter: renderer?.adapterInfo ?? null,
    closed: link?.closed ?? null,
    closing: link?.closing ?? null,
    digests_requested: link?.digestsRequested ?? null,
    frame_bytes: link?.frameBytes ?? 0,
    frame_age_ms: link?.frameAgeMs() ?? null,
    rtt_ms: link?.rttMs ?? null,
    frozen,
    reconnects,
    renders,
    render_ms: renderMs,
    error: null,
  };
  try {
    if (session) {
      Object.assign(s, {
        welcomed: session.welcomed(),
        in_sync: session.in_sync(),
        sequence: session.sequence() ?? null,
        digest: session.digest() ?? null,
        stats: plainStats(session),
      });
    }
  } catch (e) {
    report("state", e);
  }
  const all = [...errors, ...(renderer?.errors ?? []), ...(link?.error ? [link.error] : [])];
  s.error = all.length ? all.join("\n") : null;
  return s;
}

setInterval(() => overlay.update(state(), link?.frameBytes ?? 0), 250);

// ---- Test hooks (tests/browser/drive.mjs) ----

// Stops reading frames and drawing; resolves when the render in flight is done.
async function freeze() {
  frozen = true;
  link?.freeze();
  await inFlight;
}

// After freeze: one more render of the (now constant) mirror, so the
// G-buffer, AO buffer and screen all show the state the session holds.
let settledRender = null;
function settled() {
  settledRender ??= freeze().then(renderNow);
  return settledRender;
}

// The GPU's AO against the wasm's reconstruction of the same G-buffer.
async function compareCpu() {
  await settled();
  const g = await renderer.readback();
  const cpu = session.reconstruct(g.positions, g.normals, g.ids);
  const r = { width: g.width, height: g.height, pixels: g.ids.length, hit: 0, max_abs: 0, mean_abs: 0, over_tolerance: 0, hit_below_0_9: 0, hit_above_0_9: 0, mode: renderer.mode };
  let sum = 0;
  for (let i = 0; i < g.ids.length; i++) {
    const d = Math.abs(g.ao[i] - cpu[i]);
    if (!(d <= TOLERANCE)) r.over_tolerance++; // NaN counts as over
    if (!(d <= r.max_abs)) r.max_abs = Number.isNaN(d) ? Infinity : d;
    if (g.ids[i] === NO_INSTANCE) continue;
    r.hit++;
    sum += d;
    if (g.ao[i] < 0.9) r.hit_below_0_9++;
    else r.hit_above_0_9++;
  }
  r.mean_abs = r.hit ? sum / r.hit : 0; // over hit pixels (misses are 1 on both sides)
  if (renderer instanceof CpuRenderer) r.note = "CPU fallback: the wasm reconstruction compared with itself";
  return r;
}

// Resolves with state() once welcomed and the renderer is made.
const testReady = ready.then(() => state());
testReady.catch(() => {}); // a failure shows in state().error as well

window.psaoTest = {
  ready: testReady,
  state,
  dropNextFrame: () => session.drop_next_frame(),
  sendRaw: (bytes) => link.sendRaw(bytes),
  freeze,
  compareCpu,
  // The AO view's values, row-major (1 where nothing is hit), after freeze.
  aoValues: async () => {
    await settled();
    return Array.from((await renderer.readback()).ao);
  },
};
