#!/usr/bin/env bash
# Client time of PSAO against SAO on every scene of the bench set
# (scripts/bench-set.sh's groups, each at its densest N and its radius),
# with psao-eval's client_time example: many images per scene, medians.
# Usage: scripts/client-time-set.sh [extra client_time options...]
# With CLIENT_TIME="BIN_A BIN_B ..." (paths of client_time binaries, say
# each commit's target/release/examples/client_time copied out, relative to
# where the script is run or absolute), each scene is run by each binary in
# turn, the order reversed from one scene to the next, instead of by this
# checkout's build.
set -euo pipefail
bins=()
if [ -n "${CLIENT_TIME:-}" ]; then
  read -r -a given <<< "$CLIENT_TIME"
  for b in "${given[@]}"; do
    [ -x "$b" ] || { echo "CLIENT_TIME: $b is not an executable file" >&2; exit 2; }
    bins+=("$(realpath "$b")")
  done
fi
cd "$(dirname "$0")/.."
shared=../shared/scenes
if [ "${#bins[@]}" -eq 0 ]; then
  cargo build --release -p psao-eval --example client_time
  bins=(target/release/examples/client_time)
fi
turn=0
ct() {
  local order=("${bins[@]}")
  if [ $((turn % 2)) -eq 1 ]; then
    order=()
    for ((i = ${#bins[@]} - 1; i >= 0; i--)); do order+=("${bins[$i]}"); done
  fi
  turn=$((turn + 1))
  for b in "${order[@]}"; do
    if [ "${#bins[@]}" -gt 1 ]; then echo -n "$b: "; fi
    "$b" "$@"
  done
}
for s in default cesium-man; do ct --scene "$s" --density 1024 --radius 0.6 "$@"; done
source scripts/bench-set-scenes.sh
for m in "${metre_models[@]}"; do
  ct --gltf "$shared/$m" --density 1024 --radius 0.6 "$@"
done
ct --scene hall --density 256 --radius 0.6 "$@"
ct --gltf "$shared/FlightHelmet/FlightHelmet.gltf" --density 65536 --radius 0.05 "$@"
ct --gltf "$shared/Fox/Fox.glb" --density 0.2 --radius 15 "$@"
ct --gltf "$shared/CornellBox/CornellBox.glb" --density 0.04 --radius 60 "$@"
ct --gltf "$shared/ToyCar/ToyCar.gltf" --density 4000000 --radius 0.005 "$@"
ct --gltf "$shared/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.gltf" --density 400000000 --radius 0.0005 "$@"
