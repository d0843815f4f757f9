#!/usr/bin/env bash
# The built-in demo: generate a scan-like mesh, simplify it to 1% out of core under a
# memory budget smaller than an in-core run needs, then measure the result against the
# input with `qemflow compare`.
set -euo pipefail
BUILD_DIR=${1:-build}
Q="$BUILD_DIR/apps/qemflow"
OUT=${QEMFLOW_DEMO_DIR:-$BUILD_DIR/demo}
FACES=${QEMFLOW_DEMO_FACES:-1M}
BUDGET=${QEMFLOW_DEMO_BUDGET:-96M}
mkdir -p "$OUT"
echo "== qemflow gen: a scan-like blob of $FACES faces"
"$Q" gen "$OUT/blob.ply" --faces "$FACES" --shape blob --seed 1
"$Q" info "$OUT/blob.ply"
echo "== qemflow simplify: 1% out of core under --mem-budget $BUDGET"
"$Q" simplify "$OUT/blob.ply" "$OUT/blob-1pct.ply" --ratio 0.01 --mem-budget "$BUDGET" \
  --report "$OUT/report.json"
echo "== qemflow compare: error and topology of the result"
"$Q" compare "$OUT/blob.ply" "$OUT/blob-1pct.ply"
echo "== the same simplification in core (no budget): is the file the same?"
"$Q" simplify "$OUT/blob.ply" "$OUT/blob-1pct-in-core.ply" --ratio 0.01 --in-core
if cmp -s "$OUT/blob-1pct.ply" "$OUT/blob-1pct-in-core.ply"; then
  echo "yes: the out-of-core output is byte-identical to the in-core output"
else
  echo "NO: the outputs differ (a bug: please report it)"; exit 1
fi
echo "== files in $OUT: blob.ply, blob-1pct.ply, blob-1pct-in-core.ply, report.json"
