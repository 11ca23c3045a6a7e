#!/usr/bin/env bash
# Decode+apply in WebAssembly (Node) against native, on the codec bench's
# stream (the test kit's synthetic scene, 120 frames, as codec_throughput
# and psao-ffi's c_boundary) and on any capture files given: psao-wasm's
# `decode_capture` example natively (zstd through libzstd) and
# psao-wasm/tests/node/decode_capture.mjs on the wasm32 build bound with
# wasm-bindgen --target nodejs (zstd through ruzstd), alternately, ROUNDS
# times (default 3), REPS passes each (default 30). Prints one table row per
# pair with the wasm/native ratio of the best passes, and the module's size.
#
#   scripts/wasm-bench.sh [CAPTURE ...]
#
# Needs Node; the wasm32 target and wasm-bindgen-cli 0.2.130 are found or
# installed as scripts/build-web.sh does (scripts/wasm-bindgen.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
rounds="${ROUNDS:-3}"
reps="${REPS:-30}"
# shellcheck source=scripts/wasm-bindgen.sh
. scripts/wasm-bindgen.sh
command -v node >/dev/null || { echo "node not found" >&2; exit 1; }
cargo build -q -p psao-wasm --release --target wasm32-unknown-unknown
"$wbg" --target nodejs --out-dir target/psao-wasm-node \
  target/wasm32-unknown-unknown/release/psao_wasm.wasm
cargo build -q --release -p psao-wasm --example decode_capture --example bench_stream
out=target/wasm-bench
mkdir -p "$out"
target/release/examples/bench_stream "$out" >&2
captures=("$out/bench-none.cap" "$out/bench-lz4.cap" "$out/bench-zstd3.cap" "$@")
best() { sed -n 's/.*best \([0-9.]*\) ms.*/\1/p'; }
echo "wasm module (wasm-bindgen, nodejs): $(stat -c %s target/psao-wasm-node/psao_wasm_bg.wasm) bytes; node $(node --version)"
echo
echo "| capture | round | frames | native best pass (ms) | wasm best pass (ms) | wasm / native | wasm per frame (us) |"
echo "|---|---|---|---|---|---|---|"
for round in $(seq 1 "$rounds"); do
  for cap in "${captures[@]}"; do
    n=$(target/release/examples/decode_capture "$cap" "$reps")
    w=$(node psao-wasm/tests/node/decode_capture.mjs target/psao-wasm-node "$cap" "$reps")
    frames=$(sed -n 's/^native: \([0-9]*\) frames.*/\1/p' <<<"$n")
    nb=$(best <<<"$n"); wb=$(best <<<"$w")
    awk -v c="$(basename "$cap")" -v r="$round" -v f="$frames" -v n="$nb" -v w="$wb" \
      'BEGIN { printf "| %s | %d | %d | %.3f | %.3f | %.2f | %.2f |\n", c, r, f, n, w, w / n, w * 1000 / f }'
  done
done
