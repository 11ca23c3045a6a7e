#!/usr/bin/env bash
# Builds what `psao serve --web` serves beside its page: psao-wasm for
# wasm32-unknown-unknown and its wasm-bindgen glue for the web, into
# target/psao-web/pkg (psao_wasm.js, psao_wasm_bg.wasm).
#
# Needs the wasm32 target (`rustup target add wasm32-unknown-unknown`) and
# wasm-bindgen-cli 0.2.130, the version psao-wasm pins: found on PATH, in
# $WASM_BINDGEN, or installed into target/wasm-bindgen-cli (about 3 min).
set -euo pipefail
cd "$(dirname "$0")/.."
rustup target add wasm32-unknown-unknown >/dev/null 2>&1 || true
wbg="${WASM_BINDGEN:-}"
if [ -z "$wbg" ]; then
  if command -v wasm-bindgen >/dev/null && wasm-bindgen --version | grep -q " 0.2.130"; then
    wbg=wasm-bindgen
  else
    wbg="$PWD/target/wasm-bindgen-cli/bin/wasm-bindgen"
    if [ ! -x "$wbg" ]; then
      echo "installing wasm-bindgen-cli 0.2.130 into target/wasm-bindgen-cli" >&2
      cargo install wasm-bindgen-cli --version 0.2.130 --root "$PWD/target/wasm-bindgen-cli"
    fi
  fi
fi
cargo build -p psao-wasm --release --target wasm32-unknown-unknown
"$wbg" --target web --out-dir target/psao-web/pkg \
  target/wasm32-unknown-unknown/release/psao_wasm.wasm
ls -l target/psao-web/pkg >&2
