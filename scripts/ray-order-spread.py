#!/usr/bin/env python3
"""How well each quarter of a point's rays is spread, for three cast orders
of early decisions (BENCHMARKS.md, "Issue 15 and 20: what the ray lattice
does to the rest"): the bit-reversed order psao uses (psao-scene's
`early::ray_order`), a farthest-point order, and that order dealt round
the four quarters. Rays lie on psao-scene's lattice (`PointRays::ray`):
ray k of n in elevation band k, its azimuth stepping by the golden ratio.
For the run of a quarter of the rays starting at each quarter (where the
rotation starts a step), it prints the widest gap in azimuth (turns) and
how many of the four quarters of the bands it reaches.
Usage: scripts/ray-order-spread.py [N ...]   (default 24 32 64 128)"""
import math
import sys

GOLDEN = 0x9E3779B9


def lattice(n):
    return [((k + 0.5) / n, (((k * GOLDEN) & 0xFFFFFFFF) >> 8) / (1 << 24)) for k in range(n)]


def farthest(n):
    at = lattice(n)

    def d2(i, j):
        da = abs(at[i][1] - at[j][1])
        return (at[i][0] - at[j][0]) ** 2 + min(da, 1 - da) ** 2

    nearest, taken, order, nxt = [math.inf] * n, [False] * n, [], 0
    for _ in range(n):
        taken[nxt] = True
        order.append(nxt)
        best = None
        for k in range(n):
            if not taken[k]:
                nearest[k] = min(nearest[k], d2(k, nxt))
                if best is None or nearest[k] > best[0]:
                    best = (nearest[k], k)
        if best is None:
            break
        nxt = best[1]
    return order


def dealt(n):
    o = farthest(n)
    return [o[j] for q in range(4) for j in range(q, n, 4)]


def bit_reversed(n):
    return sorted(range(n), key=lambda k: int(format(k, "032b")[::-1], 2))


def report(name, order, n):
    at, m = lattice(n), (n + 3) // 4
    cells = []
    for q in range(4):
        ks = [order[(j + q * m) % n] for j in range(m)]
        a = sorted(at[k][1] for k in ks)
        gap = max([a[i + 1] - a[i] for i in range(len(a) - 1)] + [a[0] + 1 - a[-1]])
        bands = len({int(at[k][0] * 4) for k in ks})
        cells.append(f"gap {gap:.2f}, {bands} bands")
    print(f"{n:5} rays  {name:13} " + " | ".join(cells))


for n in [int(a) for a in sys.argv[1:]] or [24, 32, 64, 128]:
    report("bit-reversed", bit_reversed(n), n)
    report("farthest", farthest(n), n)
    report("dealt", dealt(n), n)
