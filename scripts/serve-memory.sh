#!/usr/bin/env bash
# Setup time and memory of `psao serve` on the hall, two builds side by side:
# BEFORE and AFTER are psao binaries (for example one built with
# `--no-default-features --features flip`, on the system allocator, and the
# default build, on jemalloc). Each line is the server's own summary.
#   scripts/serve-memory.sh BEFORE AFTER [DENSITIES...]
set -euo pipefail
before=$1 after=$2
shift 2
densities=${*:-128 512 2048}
for d in $densities; do
  for bin in "$before" "$after"; do
    line=$("$bin" serve --bind 127.0.0.1:0 --scene hall --density "$d" --rays 16 --seconds 0.1 2>&1 \
      | grep -a "scene ready")
    echo "density $d, $bin: $line"
  done
done
