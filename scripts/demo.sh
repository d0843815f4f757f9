#!/usr/bin/env bash
# The built-in demo: generate a scan-like mesh, simplify it, measure the result.
set -euo pipefail
BUILD_DIR=${1:-build}
Q="$BUILD_DIR/apps/qemflow"
OUT=${QEMFLOW_DEMO_DIR:-$BUILD_DIR/demo}
mkdir -p "$OUT"
"$Q" gen "$OUT/blob.ply" --faces 2000000 --shape blob --seed 1
"$Q" info "$OUT/blob.ply"
