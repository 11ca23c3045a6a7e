#!/usr/bin/env bash
# Runs `psao conformance client --cases CASES` RUNS times, each against a
# freshly started `psao serve` on loopback, and counts the runs in which a
# case needed a second attempt (its connection ended with no application
# close: a stateless reset or a lost close). BENCHMARKS.md, issue 16.
# Usage: scripts/conformance-soak.sh [RUNS] [CASES] [PSAO]
set -euo pipefail
runs=${1:-30}
cases=${2:-uplink.}
psao=${3:-target/release/psao}
out=$(mktemp -d)
retried=0
failed=0
server=""
trap '[ -n "$server" ] && kill "$server" 2>/dev/null || true' EXIT
for i in $(seq 1 "$runs"); do
  port=$((20000 + i))
  "$psao" serve --bind 127.0.0.1:$port > "$out/serve$i.log" 2>&1 &
  server=$!
  for _ in $(seq 1 240); do grep -q "certificate SHA-256" "$out/serve$i.log" && break; sleep 0.25; done
  fp=$(grep -o "certificate SHA-256 [0-9a-f]*" "$out/serve$i.log" | cut -d" " -f3 || true)
  if [ -z "$fp" ]; then echo "run $i: psao serve printed no fingerprint ($out/serve$i.log)" >&2; exit 1; fi
  # A server idle for 0 to 6 s before the first case.
  sleep $((i % 4 * 2))
  "$psao" conformance client --connect 127.0.0.1:$port --fingerprint "$fp" --cases "$cases" \
    --json "$out/r$i.json" > "$out/client$i.log" 2>&1 || true
  kill "$server" 2>/dev/null || true
  wait "$server" 2>/dev/null || true
  if [ ! -s "$out/r$i.json" ]; then
    failed=$((failed + 1))
  elif grep -q '"attempts": *[2-9]' "$out/r$i.json"; then
    retried=$((retried + 1))
  fi
done
server=""
echo "$retried of $runs runs had a case that ended without an application close; $failed runs wrote no report (outputs in $out)"
