#!/usr/bin/env bash
# Flipped faces (`qemflow compare`: a face whose normal opposes the nearest original
# face's) of in-core runs on generated meshes at many targets, where a single run says
# little: two 16k blobs at 10 targets from 4000 to 300 faces, a 50k figure and a 50k
# terrain at 5000-500 faces (28 runs). Prints one line per run with flips, then the total.
#
#   bench/flips.sh [BUILD_DIR] [-- extra simplify arguments]
#   e.g. bench/flips.sh build -- --charge-from 2
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(dirname "$here")"
build="${1:-$repo/build}"
shift || true
[ "${1:-}" = "--" ] && shift
Q="$build/apps/qemflow"
work="$(mktemp -d /tmp/qemflow-flips.XXXXXX)"
trap 'rm -rf "$work"' EXIT
"$Q" gen "$work/blob16k-1.ply" --faces 16000 --quiet
"$Q" gen "$work/blob16k-7.ply" --faces 16000 --seed 7 --quiet
"$Q" gen "$work/figure50k.ply" --faces 50000 --shape figure --quiet
"$Q" gen "$work/terrain50k.ply" --faces 50000 --shape terrain --quiet
total=0
extra=("$@")
run() {  # mesh target
  "$Q" simplify "$work/$1" "$work/out.ply" --target-faces "$2" --in-core --quiet ${extra[@]+"${extra[@]}"}
  local f
  f=$("$Q" compare "$work/$1" "$work/out.ply" --json 2>/dev/null |
    /usr/bin/python3 -c "import json,sys;t=sys.stdin.read();print(json.loads(t[t.find('{'):])['flipped_faces'])")
  if [ "$f" -gt 0 ]; then echo "$1 $2: $f"; fi
  total=$((total + f))
}
for m in blob16k-1.ply blob16k-7.ply; do
  for t in 4000 3000 2000 1500 1200 1100 1000 700 500 300; do run "$m" "$t"; done
done
for m in figure50k.ply terrain50k.ply; do
  for t in 5000 2000 1000 500; do run "$m" "$t"; done
done
echo "total flipped faces in 28 runs: $total"
