#!/usr/bin/env python3
"""The bench set's summary table (BENCHMARKS.md, "The bench set") from the
outputs of scripts/bench-set.sh: per scene, its triangles and coverage
(bench.md), and at the densest PSAO configuration its points, setup,
keyframe, server and client time and PSNR, beside SAO and RTAO-4spp.
Usage: scripts/bench-set-table.py [OUT]"""
import csv
import re
import sys
from pathlib import Path

out = Path(sys.argv[1] if len(sys.argv) > 1 else "bench-set-out")
print("| scene | group (radius) | triangles | pixels covered | PSAO N | points | setup s | keyframe kB | server ms/tick | client ms | PSAO PSNR | SAO PSNR | RTAO-4spp PSNR | dark-where-open px (PSAO) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for group in sorted(p for p in out.iterdir() if (p / "bench.csv").exists()):
    md = (group / "bench.md").read_text()
    radius = re.search(r"\(radius ([0-9.e+-]+)\)", md).group(1)
    facts = {m.group(1): (m.group(2), m.group(3)) for m in re.finditer(
        r"### (\S+)\n\n(\d+) triangles, (\d+)% of pixels covered", md)}
    rows = list(csv.DictReader((group / "bench.csv").open()))
    for scene in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == scene]
        psao = max((r for r in mine if r["method"] == "psao"), key=lambda r: float(r["density"]))
        sao = next(r for r in mine if r["method"] == "sao")
        rtao = next(r for r in mine if r["label"] == "RTAO-4spp")
        tris, cov = facts.get(scene, ("?", "?"))
        print(f"| {scene} | {group.name} ({radius}) | {tris} | {cov}% | {psao['density']} | {int(psao['points']):,} "
              f"| {float(psao['setup_s']):.2f} | {int(psao['keyframe_bytes']) / 1000:.1f} | {float(psao['server_ms']):.2f} "
              f"| {float(psao['client_ms']):.2f} | {float(psao['psnr_db']):.2f} | {float(sao['psnr_db']):.2f} "
              f"| {float(rtao['psnr_db']):.2f} | {float(psao['dark_where_open_px']) * 100:.3f}% |")
