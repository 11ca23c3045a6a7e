// Decode+apply of a capture file (spec/capture.md) in WebAssembly on Node:
// the wasm half of the comparison with psao-wasm's `decode_capture`
// example (BENCHMARKS.md). Each repetition decodes every frame into a
// fresh decoder.
//
// node psao-wasm/tests/node/decode_capture.mjs PKG_DIR FILE [REPS]
import { createRequire } from "node:module";
import { readFileSync } from "node:fs";
import { resolve } from "node:path";

const [pkg, file, repsArg] = process.argv.slice(2);
const reps = Number(repsArg ?? 20);
const require = createRequire(import.meta.url);
const { WasmDecoder } = require(resolve(pkg, "psao_wasm.js"));

const buf = readFileSync(file);
if (buf.subarray(0, 8).toString("latin1") !== "PSAOCAP1") throw new Error("not a capture file");
const frames = [];
for (let at = 16; at < buf.length; ) {
  const len = buf.readUInt32LE(at + 8);
  frames.push(new Uint8Array(buf.buffer, buf.byteOffset + at + 12, len));
  at += 12 + len;
}
const bytes = frames.reduce((n, f) => n + f.length, 0);
let best = Infinity;
let total = 0;
for (let r = 0; r < reps; r++) {
  const d = WasmDecoder.with_default_limits();
  const t = process.hrtime.bigint();
  for (const f of frames) d.receive(f).free();
  const s = Number(process.hrtime.bigint() - t) / 1e9;
  best = Math.min(best, s);
  total += s;
  if (d.digest() === undefined) throw new Error("no state after the capture");
  d.free();
}
console.log(
  `wasm: ${frames.length} frames, ${bytes} bytes; best ${(best * 1e3).toFixed(3)} ms, mean ${((total / reps) * 1e3).toFixed(3)} ms per pass (${((best * 1e6) / frames.length).toFixed(2)} us per frame, ${(bytes / best / 1e6).toFixed(0)} MB/s at best)`,
);
