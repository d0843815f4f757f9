#!/usr/bin/env bash
# Throughput against memory budget (issue 5): one generated mesh simplified to 1% at each
# --mem-budget; writes bench/results/budget_sweep.csv and budget_sweep.png (faces/s and
# peak RSS against budget, plotted by bench/budget_sweep.py).
#
#   bench/budget_sweep.sh [FACES] [BUILD_DIR] [WORK_DIR] [BUDGETS...]
#   bench/budget_sweep.sh 50M build /tmp/qemflow-sweep 256M 512M 1G 2G 4G 8G   (the defaults)
#   CSV=bench/results/budget_sweep_5M.csv bench/budget_sweep.sh 5M ...   write the CSV (and the
#   PNG beside it, same name) elsewhere
set -euo pipefail
FACES=${1:-50M}
BUILD=${2:-build}
WORK=${3:-/tmp/qemflow-sweep}
shift $(( $# < 3 ? $# : 3 )) || true
BUDGETS=("$@")
[ ${#BUDGETS[@]} -eq 0 ] && BUDGETS=(256M 512M 1G 2G 4G 8G)
HERE=$(cd "$(dirname "$0")" && pwd)
QEMFLOW="$BUILD/apps/qemflow"
CSV=${CSV:-$HERE/results/budget_sweep.csv}
PNG="${CSV%.csv}.png"
mkdir -p "$WORK" "$HERE/results"
trap 'rm -rf "$WORK"' EXIT

echo "generating $FACES faces..." >&2
"$QEMFLOW" gen "$WORK/in.ply" --faces "$FACES" --quiet >&2
echo "faces,budget,budget_bytes,patches,epochs,out_of_core_epochs,in_core_faces,wall_s,cpu_s,load1,faces_per_s,peak_rss_bytes,scratch_read_bytes,scratch_written_bytes,io_busy_pct,patch_splits,commit" > "$CSV"
for BUDGET in "${BUDGETS[@]}"; do
  echo "simplify at --mem-budget $BUDGET..." >&2
  LOAD=$(cut -d' ' -f1 /proc/loadavg)  # wall time follows the machine's load; CPU seconds much less
  if ! "$QEMFLOW" simplify "$WORK/in.ply" "$WORK/out.ply" --ratio 0.01 --mem-budget "$BUDGET" --scratch "$WORK" \
      --report "$WORK/report.json" --quiet; then
    echo "  (refused or failed at $BUDGET)" >&2
    continue
  fi
  COMMIT=$(git -C "$HERE" rev-parse --short HEAD 2>/dev/null || echo unknown)
  /usr/bin/python3 - "$WORK/report.json" "$FACES" "$BUDGET" "$LOAD" "$COMMIT" >> "$CSV" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
wall = r["wall_seconds"]
io = 100 * r["io_busy_seconds"] / wall if wall else 0
print(f"{sys.argv[2]},{sys.argv[3]},{r['budget_bytes']},{r['patches']},{r['epochs']},{r['out_of_core_epochs']},"
      f"{r['in_core_faces']},{wall:.2f},{r['cpu_seconds']:.1f},{sys.argv[4]},{r['input_faces'] / wall:.0f},"
      f"{r['peak_rss_bytes']},{r['scratch_bytes_read']},{r['scratch_bytes_written']},{io:.0f},"
      f"{r.get('patch_splits', 0)},{sys.argv[5]}")
PY
  rm -f "$WORK/out.ply"
done
cat "$CSV"
/usr/bin/python3 "$HERE/budget_sweep.py" "$CSV" "$PNG"
