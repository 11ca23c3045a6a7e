# Sourced by scripts/build-web.sh and scripts/wasm-bench.sh from the
# repository's root: sets `wbg` to a wasm-bindgen 0.2.130 (the version
# psao-wasm pins), from $WASM_BINDGEN, the PATH, or installed into
# target/wasm-bindgen-cli (about 3 min), and adds the wasm32 target.
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
