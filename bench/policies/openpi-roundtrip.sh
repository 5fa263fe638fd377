#!/usr/bin/env bash
# Per-act round trip of Assay's openpi client against openpi's own Python client
# (openpi-client 0.1.2 from PyPI), side by side in one run, on the same server (the policy kit's
# openpi server answering zeros) and the same observation: two 224×224 RGB images, a float32
# state of 8, a prompt. The clients take turns, ROUNDS times, N calls each.
#
#   bench/policies/openpi-roundtrip.sh [N] [ROUNDS]        (needs scripts/test's venv)
set -euo pipefail
cd "$(dirname "$0")/../.."
. scripts/env.sh
N=${1:-300}
ROUNDS=${2:-3}
PY="${ASSAY_TEST_PYTHON:-$HOME/.cache/assay/test-venv/bin/python}"
cargo build -q -p assay-policy --example openpi_roundtrip
RUST="$CARGO_TARGET_DIR/debug/examples/openpi_roundtrip"
out=$(mktemp)
"$PY" tests/python/serve_policy.py --protocol openpi --policy zeros --port 0 > "$out" 2>/dev/null &
server=$!
trap 'kill $server 2>/dev/null; rm -f "$out"' EXIT
for _ in $(seq 100); do grep -q listening "$out" && break; sleep 0.1; done
url=$(sed -n 's/^listening on //p' "$out")
for r in $(seq "$ROUNDS"); do
  "$PY" tests/python/openpi_roundtrip.py --url "$url" --n "$N" --size 224
  "$RUST" "$url" "$N" 224
done
