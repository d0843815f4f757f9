#!/usr/bin/env bash
# In-core quality of `qemflow simplify` alone (no peers): output faces, epochs and the
# symmetric `qemflow compare` errors ÷ bbox diagonal, on the shared meshes and a
# generated 1M-face blob and terrain, at 1% (and 0.1% for the dragon and the blob).
#
#   bench/quality.sh [BUILD_DIR]      (default build/; the shared meshes from ../shared/data)
#   SIMPLIFY_ARGS="--cut-rise 1" DATA_DIR=/work/shared/data bench/quality.sh
#     (extra `qemflow simplify` arguments; the shared meshes from elsewhere, e.g. in a worktree)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(dirname "$here")"
Q="${1:-$repo/build}/apps/qemflow"
D="${DATA_DIR:-$repo/../shared/data}"
work="$(mktemp -d /tmp/qemflow-quality.XXXXXX)"
trap 'rm -rf "$work"' EXIT
"$Q" gen "$work/blob-1M.ply" --faces 1M --seed 1 --quiet
"$Q" gen "$work/terrain-1M.ply" --shape terrain --faces 1M --seed 1 --quiet
echo "mesh,ratio,output_faces,epochs,rms_rel,hausdorff_rel"
run() {  # name input ratio
  [ -f "$2" ] || { echo "$1,$3,skipped (no $2)"; return; }
  # shellcheck disable=SC2086  # SIMPLIFY_ARGS is a list of arguments
  "$Q" simplify "$2" "$work/out.ply" --ratio "$3" --in-core --quiet --report "$work/r.json" ${SIMPLIFY_ARGS:-}
  "$Q" compare "$2" "$work/out.ply" --json > "$work/c.json" 2>/dev/null
  /usr/bin/python3 - "$1" "$3" "$work/r.json" "$work/c.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[3]))
t = open(sys.argv[4]).read()
s = json.loads(t[t.find('{'):])["distances"]["symmetric"]["relative"]
print(f"{sys.argv[1]},{sys.argv[2]},{r['output_faces']},{r['epochs']},{s['rms']:.3g},{s['hausdorff']:.3g}")
PY
}
run dragon "$D/stanford-dragon.ply.zst" 0.01
run dragon "$D/stanford-dragon.ply.zst" 0.001
run igea "$D/igea.ply.zst" 0.01
run bunny "$D/stanford-bunny.ply.zst" 0.01
run blob-1M "$work/blob-1M.ply" 0.01
run blob-1M "$work/blob-1M.ply" 0.001
run terrain-1M "$work/terrain-1M.ply" 0.01
