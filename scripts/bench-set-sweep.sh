#!/usr/bin/env bash
# The bench set of BENCHMARKS.md at five densities per group, doubling up
# to the densest of scripts/bench-set.sh (SWEEP=1 there): the issue 15
# check "PSNR rises with N at every step" on every scene ("Issue 15: rays
# on a Fibonacci lattice", "what the ray lattice does to the rest"). About
# 7 minutes on 2 cores.
# Usage: scripts/bench-set-sweep.sh [OUT] [extra psao bench options...]
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-set-sweep-out}
shift || true
SWEEP=1 scripts/bench-set.sh "$out" "$@"
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
