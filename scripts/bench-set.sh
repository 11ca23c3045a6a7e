#!/usr/bin/env bash
# The bench set of BENCHMARKS.md ("The bench set"): psao bench on the
# embedded scenes and on every model in ../shared/scenes, grouped by the
# scale their units need (the AO radius and densities are per run).
# SWEEP=1 runs each group at five densities, doubling up to its densest,
# instead of two (scripts/bench-set-sweep.sh); DENSEST=1 at its densest
# alone (as for the ray budget's table: `--ray-budget auto`).
# Usage: [SWEEP=1 | DENSEST=1] scripts/bench-set.sh [OUT] [extra psao bench options...]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-set-out}
shift || true
shared=../shared/scenes
sweep=${SWEEP:-0}
densest=${DENSEST:-0}
cargo build --release -p psao-cli --bin psao
psao=target/release/psao
common=(--frames 4 --width 320 --height 180 --reference-rays 128 --point-rays 32 --rates 60 --image-frames 0)
# run GROUP "TWO DENSITIES" "FIVE DENSITIES" [psao bench options...]
run() {
  local group=$1 two=$2 five=$3; shift 3
  local densities=$two
  [ "$sweep" = 1 ] && densities=$five
  [ "$densest" = 1 ] && densities=${two##*,}
  echo "== $group" >&2
  "$psao" bench "${common[@]}" --out "$out/$group" --densities "$densities" "$@"
}
# Metre-sized scenes, the paper's radius.
source scripts/bench-set-scenes.sh
metre=()
for m in "${metre_models[@]}"; do
  metre+=(--gltf "$shared/$m")
done
run metre 256,1024 128,256,512,1024,2048 --scenes default,cesium-man --radius 0.6 "${metre[@]}" "$@"
# The Cameras sample again, with the automatic camera instead of its own.
run cameras-auto 256,1024 128,256,512,1024,2048 --only-gltf --gltf "$shared/Cameras/Cameras.gltf" --auto-camera --radius 0.6 "$@"
run hall 64,256 16,32,64,128,256 --scenes hall --radius 0.6 "$@"
# A 0.7 m helmet: 5 cm.
run helmet 16384,65536 4096,8192,16384,32768,65536 --only-gltf --gltf "$shared/FlightHelmet/FlightHelmet.gltf" --radius 0.05 "$@"
# A 155-unit fox (centimetres): 15.
run fox 0.05,0.2 0.0125,0.025,0.05,0.1,0.2 --only-gltf --gltf "$shared/Fox/Fox.glb" --radius 15 "$@"
# A 555-unit room: 60.
run cornell 0.01,0.04 0.0025,0.005,0.01,0.02,0.04 --only-gltf --gltf "$shared/CornellBox/CornellBox.glb" --radius 60 "$@"
# A 7 cm car: 5 mm.
run toycar 1000000,4000000 250000,500000,1000000,2000000,4000000 --only-gltf --gltf "$shared/ToyCar/ToyCar.gltf" --radius 0.005 "$@"
# 7 mm of spheres: 0.5 mm.
run spheres 100000000,400000000 25000000,50000000,100000000,200000000,400000000 --only-gltf --gltf "$shared/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.gltf" --radius 0.0005 "$@"
echo "wrote $out/*/bench.md" >&2
