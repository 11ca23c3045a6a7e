#!/usr/bin/env bash
# The bench set of BENCHMARKS.md at five densities per group, doubling up
# to the densest of scripts/bench-set.sh: the issue 15 check "PSNR rises
# with N at every step" on every scene ("Issue 15: rays on a Fibonacci
# lattice", "what the ray lattice does to the rest"). About 6 minutes on
# 2 cores.
# Usage: scripts/bench-set-sweep.sh [OUT] [extra psao bench options...]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-set-sweep-out}
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
source scripts/bench-set-scenes.sh
metre=()
for m in "${metre_models[@]}"; do
  metre+=(--gltf "$shared/$m")
done
run metre --scenes default,cesium-man --densities 128,256,512,1024,2048 --radius 0.6 "${metre[@]}" "$@"
run cameras-auto --only-gltf --gltf "$shared/Cameras/Cameras.gltf" --auto-camera --densities 128,256,512,1024,2048 --radius 0.6 "$@"
run hall --scenes hall --densities 16,32,64,128,256 --radius 0.6 "$@"
run helmet --only-gltf --gltf "$shared/FlightHelmet/FlightHelmet.gltf" --densities 4096,8192,16384,32768,65536 --radius 0.05 "$@"
run fox --only-gltf --gltf "$shared/Fox/Fox.glb" --densities 0.0125,0.025,0.05,0.1,0.2 --radius 15 "$@"
run cornell --only-gltf --gltf "$shared/CornellBox/CornellBox.glb" --densities 0.0025,0.005,0.01,0.02,0.04 --radius 60 "$@"
run toycar --only-gltf --gltf "$shared/ToyCar/ToyCar.gltf" --densities 250000,500000,1000000,2000000,4000000 --radius 0.005 "$@"
run spheres --only-gltf --gltf "$shared/MetalRoughSpheresNoTextures/MetalRoughSpheresNoTextures.gltf" --densities 25000000,50000000,100000000,200000000,400000000 --radius 0.0005 "$@"
# Per scene: PSAO's PSNR at each density, and whether it rises at every step.
python3 - "$out" <<'PY'
import csv, sys
from pathlib import Path
for f in sorted(Path(sys.argv[1]).glob("*/bench.csv")):
    by_scene = {}
    for r in csv.DictReader(f.open()):
        if r["method"] == "psao":
            by_scene.setdefault(r["scene"], []).append((float(r["density"]), float(r["psnr_db"])))
    for scene, rows in by_scene.items():
        rows.sort()
        v = [p for _, p in rows]
        rises = all(b > a for a, b in zip(v, v[1:]))
        zero = all(p == float("inf") for p in v)
        print(f"{f.parent.name:13} {scene:28} " + " ".join(f"{p:6.2f}" for p in v)
              + ("  error 0 at every N" if zero else "  rises at every step" if rises else "  does NOT rise at every step"))
PY
echo "wrote $out/*/bench.md" >&2
