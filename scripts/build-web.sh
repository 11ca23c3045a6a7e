#!/usr/bin/env bash
# Builds what `psao serve --web` serves beside its page: psao-wasm for
# wasm32-unknown-unknown and its wasm-bindgen glue for the web, into
# target/psao-web/pkg (psao_wasm.js, psao_wasm_bg.wasm).
#
# Needs the wasm32 target (added if missing) and wasm-bindgen-cli 0.2.130,
# the version psao-wasm pins: found on PATH, in $WASM_BINDGEN, or installed
# into target/wasm-bindgen-cli (about 3 min; scripts/wasm-bindgen.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/wasm-bindgen.sh
. scripts/wasm-bindgen.sh
cargo build -p psao-wasm --release --target wasm32-unknown-unknown
"$wbg" --target web --out-dir target/psao-web/pkg \
  target/wasm32-unknown-unknown/release/psao_wasm.wasm
ls -l target/psao-web/pkg >&2
