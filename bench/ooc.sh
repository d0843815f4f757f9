#!/usr/bin/env bash
# Out-of-core simplification benchmark (issue 5): generated meshes simplified to 1% under a
# memory budget; one CSV row per run (wall, CPU seconds, peak RSS, faces/s, patches, epochs,
# the face count at which the run went in core, halo and gather overheads, bytes, and the
# machine's 1-minute load average when the run started: on a shared machine wall time
# follows the load, CPU seconds much less).
#
#   bench/ooc.sh [BUILD_DIR] [WORK_DIR] [FACES:BUDGET ...]
#   bench/ooc.sh build /tmp/qemflow-ooc 50M:512M 200M:4G      (the defaults)
#   SIMPLIFY_ARGS="--charge-from 2" bench/ooc.sh ...           (extra simplify arguments,
#                                                              the CSV's last column)
#   REPORTS=DIR bench/ooc.sh ...     also keep each run's --report JSON (patch phases, stages,
#                                    decimator work) as DIR/report-FACES-BUDGET.json
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

echo "faces,budget,output_faces,patches,epochs,out_of_core_epochs,in_core_faces,halo_redos,patch_per_owned,gathered_per_owned,wall_s,cpu_s,load1,peak_rss_mib,within_budget,faces_per_s,scratch_read_mib,scratch_written_mib,args"
for RUN in "${RUNS[@]}"; do
  FACES=${RUN%%:*}
  BUDGET=${RUN##*:}
  echo "generating $FACES faces..." >&2
  "$QEMFLOW" gen "$WORK/in.ply" --faces "$FACES" --quiet >&2
  echo "simplify to 1% at --mem-budget $BUDGET..." >&2
  LOAD=$(cut -d' ' -f1 /proc/loadavg)
  # SIMPLIFY_ARGS is split into words on purpose.
  # shellcheck disable=SC2086
  "$QEMFLOW" simplify "$WORK/in.ply" "$WORK/out.ply" --ratio 0.01 --mem-budget "$BUDGET" --scratch "$WORK" \
    --report "$WORK/report.json" --quiet ${SIMPLIFY_ARGS:-}
  /usr/bin/python3 - "$WORK/report.json" "$FACES" "$BUDGET" "$LOAD" "${SIMPLIFY_ARGS:-}" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
wall = r["wall_seconds"]
ok = "yes" if r["peak_rss_bytes"] <= r["budget_bytes"] else "NO"
owned = r.get("owned_faces_total", 0)
patch = r.get("patch_faces_total", 0) / owned if owned else 0
gathered = r.get("gathered_faces_total", 0) / owned if owned else 0
print(f"{sys.argv[2]},{sys.argv[3]},{r['output_faces']},{r['patches']},{r['epochs']},{r['out_of_core_epochs']},"
      f"{r['in_core_faces']},{r['halo_redos']},{patch:.2f},{gathered:.2f},{wall:.1f},{r['cpu_seconds']:.1f},"
      f"{sys.argv[4]},{r['peak_rss_bytes'] / 2**20:.0f},{ok},{r['input_faces'] / wall:.0f},"
      f"{r['scratch_bytes_read'] / 2**20:.0f},{r['scratch_bytes_written'] / 2**20:.0f},{sys.argv[5]}")
# Where the time went (stderr, beside the CSV): each stage's wall seconds, the cores its
# CPU seconds kept busy, and the share of it the I/O thread was busy.
parts = [f"{s['name']} {s['seconds']:.1f} s ({s['cpu_seconds'] / s['seconds']:.2f} cores, I/O {100 * s['io_busy_seconds'] / s['seconds']:.0f}%)"
         for s in r["stages"] if s["seconds"] >= 0.05]
print("stages: " + ", ".join(parts), file=sys.stderr)
PY
  if [ -n "${REPORTS:-}" ]; then
    mkdir -p "$REPORTS"
    cp "$WORK/report.json" "$REPORTS/report-$FACES-$BUDGET.json"
  fi
  rm -f "$WORK/in.ply" "$WORK/out.ply"
done
