#!/usr/bin/env bash
# The bench set of BENCHMARKS.md ("The bench set"): psao bench on the
# embedded scenes and on every model in ../shared/scenes, grouped by the
# scale their units need (the AO radius and densities are per run).
# Usage: scripts/bench-set.sh [OUT] [extra psao bench options...]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-set-out}
shift || true
shared=../shared/scenes
cargo build --release -p psao-cli --bin psao
psao=target/release/psao
common=(--frames 4 --width 320 --height 180 --reference-rays 128 --point-rays 32 --rates 60 --image-frames 0)
run() {
  local group=$1; shift
  echo "== $group" >&2
  "$psao" bench "${common[@]}" --out "$out/$group" "$@"
}
# Metre-sized scenes, the paper's radius.
source scripts/bench-set-scenes.sh
metre=()
for m in "${metre_models[@]}"; do
  metre+=(--gltf "$shared/$m")
done
run metre --scenes default,cesium-man --densities 256,1024 --radius 0.6 "${metre[@]}" "$@"
# The Cameras sample again, with the automatic camera instead of its own.
run cameras-auto --only-gltf --gltf "$shared/Cameras/Cameras.gltf" --auto-camera --densities 256,1024 --radius 0.6 "$@"
run hall --scenes hall --densities 64,256 --radius 0.6 "$@"
# A 0.7 m helmet: 5 cm.
run helmet --only-gltf --gltf "$shared/FlightHelmet/FlightHelmet.gltf" --densities 16384,65536 --radius 0.05 "$@"
# A 155-unit fox (centimetres): 15.
run fox --only-gltf --gltf "$shared/Fox/Fox.glb" --densities 0.05,0.2 --radius 15 "$@"
# A 555-unit room: 60.
run cornell --only-gltf --gltf "$shared/CornellBox/CornellBox.glb" --densities 0.01,0.04 --radius 60 "$@"
# A 7 cm car: 5 mm.
run toycar --only-gltf --gltf "$shared/ToyCar/ToyCar.gltf" --densities 1000000,4000000 --radius 0.005 "$@"
# 7 mm of spheres: 0.5 mm.
run spheres --only-gltf --gltf "$shared/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.gltf" --densities 100000000,400000000 --radius 0.0005 "$@"
echo "wrote $out/*/bench.md" >&2
