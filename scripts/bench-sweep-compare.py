#!/usr/bin/env python3
"""Two runs of scripts/bench-set-sweep.sh side by side (A, then B): per
group and scene, PSAO's PSNR at the group's five densities in each run,
B - A per density ("0" where the PSNR is the same to the bench's last
printed digit in bench.csv, else signed to 0.01 dB), whether each rises at
every step ("exact" where every PSNR is infinite), and SAO's PSNR from A.
Prints a markdown table (BENCHMARKS.md, "Issue 15: candidates hidden from
the view").
Usage: scripts/bench-sweep-compare.py A_DIR B_DIR [A_LABEL B_LABEL]"""
import csv
import glob
import os
import sys


def load(root):
    out = {}
    for f in sorted(glob.glob(os.path.join(root, "*", "bench.csv"))):
        group = os.path.basename(os.path.dirname(f))
        for r in csv.DictReader(open(f)):
            out.setdefault((group, r["scene"]), {})[(r["method"], r["density"])] = r
    return out


a, b = load(sys.argv[1]), load(sys.argv[2])
la, lb = (sys.argv[3], sys.argv[4]) if len(sys.argv) > 4 else ("A", "B")
print(f"| group | scene | densities | PSAO PSNR (dB), {la} | {lb} | {lb} - {la} (dB) | rises at every step, {la} / {lb} | SAO |")
print("|---|---|---|---|---|---|---|---|")
for key, ra in a.items():
    rb = b.get(key, {})
    ds = [d for (m, d) in ra if m == "psao" and ("psao", d) in rb]
    pa = [float(ra[("psao", d)]["psnr_db"]) for d in ds]
    pb = [float(rb[("psao", d)]["psnr_db"]) for d in ds]
    sao = [r for (m, _), r in ra.items() if m == "sao"]

    def rise(v):
        if all(x == float("inf") for x in v):
            return "exact"
        return "yes" if all(y > x for x, y in zip(v, v[1:])) else "**no**"

    def fmt(v):
        return ", ".join("inf" if x == float("inf") else f"{x:.2f}" for x in v)

    diff = ", ".join("0" if x == y else f"{y - x:+.2f}" for x, y in zip(pa, pb))
    saop = f"{float(sao[0]['psnr_db']):.2f}" if sao else "-"
    print(f"| {key[0]} | {key[1]} | {', '.join(ds)} | {fmt(pa)} | {fmt(pb)} | {diff} | {rise(pa)} / {rise(pb)} | {saop} |")
