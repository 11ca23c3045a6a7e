// Replays every vector of spec/vectors through psao-wasm built for
// wasm32-unknown-unknown and bound with `wasm-bindgen --target nodejs`:
// the codec's own decoder, in WebAssembly, with zstd in pure Rust. Each
// frame must give its `expect` line and each `digest` line must match.
//
// node psao-wasm/tests/node/replay.mjs PKG_DIR SPEC_VECTORS_DIR
import { createRequire } from "node:module";
import { readdirSync, readFileSync } from "node:fs";
import { join, resolve } from "node:path";

const [pkg, dir] = process.argv.slice(2);
const require = createRequire(import.meta.url);
const { WasmDecoder } = require(resolve(pkg, "psao_wasm.js"));

const unhex = (s) => Uint8Array.from(s.match(/../g).map((b) => parseInt(b, 16)));
const outcome = (r) => {
  if (r.error !== undefined) return `error ${String(r.error).split(":")[0]}`;
  const x = r.ok;
  if (x.kind === 0) return `applied ${x.sequence} ${x.keyframe ? "keyframe" : "delta"}`;
  if (x.kind === 1) return "stale";
  if (x.kind === 2) return "need_keyframe";
  return `kind ${x.kind}`;
};

let files = 0;
let checks = 0;
const failures = [];
for (const name of readdirSync(dir).filter((f) => f.endsWith(".txt")).sort()) {
  files++;
  const d = WasmDecoder.with_default_limits();
  let last;
  for (const line of readFileSync(join(dir, name), "utf8").split("\n")) {
    const [word, ...rest] = line.split(" ");
    const arg = rest.join(" ");
    if (word === "limit") {
      if (!d.set_limit(rest[0], Number(rest[1]))) failures.push(`${name}: limit ${arg} refused`);
    } else if (word === "frame") {
      try {
        const r = d.receive(unhex(arg));
        last = { ok: { kind: r.kind, sequence: r.sequence, keyframe: r.keyframe } };
        r.free();
      } catch (e) {
        last = { error: e };
      }
    } else if (word === "expect") {
      checks++;
      const got = outcome(last);
      if (got !== arg) failures.push(`${name}: expected ${arg}, got ${got}`);
    } else if (word === "digest") {
      checks++;
      const x = d.digest();
      const got = x === undefined ? "none" : (x >>> 0).toString(16).padStart(8, "0");
      if (got !== arg) failures.push(`${name}: digest ${arg}, got ${got}`);
    } else if (word === "state") {
      break;
    }
  }
  d.free();
}
if (failures.length) {
  console.error(failures.join("\n"));
  process.exit(1);
}
console.log(`${files} vectors replayed in WebAssembly (${checks} checks), all as recorded`);
