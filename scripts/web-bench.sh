#!/usr/bin/env bash
# WebTransport against native QUIC, side by side on one server: psao serve
# --web on the default scene with NATIVE native clients (psao view) and
# PAGES tabs of the browser client in one headless Chromium
# (tests/browser/hold.mjs), held HOLD seconds. Prints the server's own
# per-binding count while all are connected (frame records, their bytes
# and the UDP bytes per frame, frame age from a frame's broadcast to its
# ACK) and the pages' own figures.
#
#   scripts/web-bench.sh            # PAGES=2 NATIVE=2 HOLD=30 MODE=webgpu
#   MODE=cpu scripts/web-bench.sh   # the pages' CPU fallback
#
# Needs target/release/psao, scripts/build-web.sh's module, Chromium and
# tests/browser/node_modules (npm ci).
set -euo pipefail
cd "$(dirname "$0")/.."
PAGES=${PAGES:-2}
NATIVE=${NATIVE:-2}
HOLD=${HOLD:-30}
MODE=${MODE:-webgpu}
CHROMIUM=${PSAO_CHROMIUM:-/usr/bin/chromium}
psao=target/release/psao
out=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$out"' EXIT
"$psao" serve --bind 127.0.0.1:4533 --web --web-port 4543 --seconds $((HOLD + 90)) > "$out/serve.log" 2>&1 &
for _ in $(seq 1 100); do grep -q "^open https" "$out/serve.log" && break; sleep 0.2; done
grep -q "^open https" "$out/serve.log" || { cat "$out/serve.log"; exit 1; }
fp=$(grep -o "^certificate SHA-256 [0-9a-f]*" "$out/serve.log" | awk '{print $3}')
spki=$(grep -o "spki-list=[^)]*" "$out/serve.log" | head -1 | sed 's/^spki-list=//')
for k in $(seq 1 "$NATIVE"); do
  "$psao" view --connect 127.0.0.1:4533 --fingerprint "$fp" --seconds $((HOLD + 60)) > "$out/view-$k.log" 2>&1 &
done
flag=""; [ "$MODE" = cpu ] && flag="--cpu"
node tests/browser/hold.mjs --url https://127.0.0.1:4543/ --spki "$spki" --chromium "$CHROMIUM" \
  --pages "$PAGES" --seconds "$HOLD" $flag > "$out/hold.json"
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')"
echo "pages ($MODE), over the hold: $(cat "$out/hold.json")"
echo "server, all clients connected:"
grep "clients by binding" "$out/serve.log" | grep "WebTransport" | grep "native" | tail -1 | sed 's/^clients by binding: /  /; s/ | /\n  /g'
