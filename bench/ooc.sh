#!/usr/bin/env bash
# Out-of-core simplification benchmark (issue 5): generated meshes simplified to 1% under a
# memory budget; one CSV row per run (wall, peak RSS, faces/s, patches, epochs, bytes).
#
#   bench/ooc.sh [BUILD_DIR] [WORK_DIR] [FACES:BUDGET ...]
#   bench/ooc.sh build /tmp/qemflow-ooc 50M:512M 200M:4G      (the defaults)
#
# Every file it makes lives in WORK_DIR and is deleted at exit.
set -euo pipefail
BUILD=${1:-build}
WORK=${2:-/tmp/qemflow-ooc}
shift $(( $# < 2 ? $# : 2 )) || true
RUNS=("$@")
[ ${#RUNS[@]} -eq 0 ] && RUNS=(50M:512M 200M:4G)
QEMFLOW="$BUILD/apps/qemflow"
mkdir -p "$WORK"
trap 'rm -rf "$WORK"' EXIT

echo "faces,budget,output_faces,patches,epochs,out_of_core_epochs,halo_redos,wall_s,peak_rss_mib,within_budget,faces_per_s,scratch_read_mib,scratch_written_mib"
for RUN in "${RUNS[@]}"; do
  FACES=${RUN%%:*}
  BUDGET=${RUN##*:}
  echo "generating $FACES faces..." >&2
  "$QEMFLOW" gen "$WORK/in.ply" --faces "$FACES" --quiet >&2
  echo "simplify to 1% at --mem-budget $BUDGET..." >&2
  "$QEMFLOW" simplify "$WORK/in.ply" "$WORK/out.ply" --ratio 0.01 --mem-budget "$BUDGET" --scratch "$WORK" \
    --report "$WORK/report.json" --quiet
  /usr/bin/python3 - "$WORK/report.json" "$FACES" "$BUDGET" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
wall = r["wall_seconds"]
ok = "yes" if r["peak_rss_bytes"] <= r["budget_bytes"] else "NO"
print(f"{sys.argv[2]},{sys.argv[3]},{r['output_faces']},{r['patches']},{r['epochs']},{r['out_of_core_epochs']},"
      f"{r['halo_redos']},{wall:.1f},{r['peak_rss_bytes'] / 2**20:.0f},{ok},{r['input_faces'] / wall:.0f},"
      f"{r['scratch_bytes_read'] / 2**20:.0f},{r['scratch_bytes_written'] / 2**20:.0f}")
PY
  rm -f "$WORK/in.ply" "$WORK/out.ply"
done
