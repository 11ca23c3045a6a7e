#!/usr/bin/env python3
"""Side by side, per scene and PSAO density at the first rate: two psao
bench outputs (A, then B; e.g. overflow chains against --no-overflow), with
dropped points, keyframe kB, Mbit/s, client ms and PSNR of each, and SAO's
PSNR and client ms from A.
Usage: scripts/bench-compare.py A_DIR B_DIR [A_LABEL B_LABEL]
(each DIR holds a bench.csv, or groups of them one folder down)."""
import csv
import sys
from pathlib import Path


def rows(root):
    files = [root / "bench.csv"] if (root / "bench.csv").exists() else sorted(root.glob("*/bench.csv"))
    out = {}
    for f in files:
        for r in csv.DictReader(f.open()):
            out[(r["scene"], r["method"], r["label"], r["density"], r["rate_hz"])] = r
    return out


a, b = rows(Path(sys.argv[1])), rows(Path(sys.argv[2]))
la, lb = (sys.argv[3], sys.argv[4]) if len(sys.argv) > 4 else ("A", "B")
print(f"| scene | N | dropped, {la} / {lb} | keyframe kB, {la} / {lb} | Mbit/s, {la} / {lb} | client ms, {la} / {lb} (ratio) | PSNR {la} | PSNR {lb} | {la} - {lb} dB | SAO PSNR | {la} over SAO | SAO client ms | {la} client / SAO |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for key, ra in a.items():
    scene, method, _, density, rate = key
    if method != "psao" or key not in b:
        continue
    rb = b[key]
    sao = next((r for k, r in a.items() if k[0] == scene and k[1] == "sao"), None)
    ca, cb = float(ra["client_ms"]), float(rb["client_ms"])
    pa, pb = float(ra["psnr_db"]), float(rb["psnr_db"])
    sp = float(sao["psnr_db"]) if sao else float("nan")
    sc = float(sao["client_ms"]) if sao else float("nan")
    print(f"| {scene} | {density} | {int(ra['dropped_points']):,} / {int(rb['dropped_points']):,} "
          f"| {int(ra['keyframe_bytes']) / 1000:.1f} / {int(rb['keyframe_bytes']) / 1000:.1f} "
          f"| {float(ra['mbit_s']):.3f} / {float(rb['mbit_s']):.3f} "
          f"| {ca:.2f} / {cb:.2f} ({ca / cb if cb else float('nan'):.2f}x) "
          f"| {pa:.2f} | {pb:.2f} | {pa - pb:+.2f} | {sp:.2f} | {pa - sp:+.2f} | {sc:.2f} | {ca / sc if sc else float('nan'):.2f}x |")
