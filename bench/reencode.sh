#!/usr/bin/env bash
# End-to-end benchmark of the engine's re-encode pipeline (what `qemflow simplify IN OUT
# --ratio 1` runs): a generated mesh re-encoded through uniform-grid blocks at several
# memory budgets, against two I/O floors measured by the same driver on the I/O thread
# alone, no compute: reading the input and writing as many bytes as the output (the
# floor of the issue's target), and that plus writing and reading back as many scratch
# bytes as the run did (the floor for every byte the run moved).
#
#   bench/reencode.sh [FACES] [BUILD_DIR] [WORK_DIR] [BUDGETS...]
#   bench/reencode.sh 100M build /tmp/qemflow-reencode 256M 1G 4G     (the defaults)
#   SCRATCH_CODEC=zstd bench/reencode.sh ...    force the scratch codec (default: auto)
#   CSV=bench/results/reencode.csv bench/reencode.sh ...   also write the rows as CSV
#
# Prints a Markdown table; every file it makes lives in WORK_DIR and is deleted at exit.
# The machine may be shared: each row carries the 1-minute load average at its end, and
# CPU seconds (user + system of the whole process) beside wall seconds.
set -euo pipefail
FACES=${1:-100M}
BUILD=${2:-build}
WORK=${3:-/tmp/qemflow-reencode}
shift $(( $# < 3 ? $# : 3 )) || true
BUDGETS=("$@")
[ ${#BUDGETS[@]} -eq 0 ] && BUDGETS=(256M 1G 4G)

QEMFLOW="$BUILD/apps/qemflow"
DRIVER="$BUILD/bench/engine_bench"
mkdir -p "$WORK"
trap 'rm -rf "$WORK"' EXIT

echo "generating $FACES faces..." >&2
"$QEMFLOW" gen "$WORK/in.ply" --faces "$FACES" >&2
IN_BYTES=$(stat -c %s "$WORK/in.ply")

echo "I/O floor..." >&2
# Each floor is the best of two runs (the machine may be shared).
"$DRIVER" io-baseline "$WORK/in.ply" "$WORK" "$IN_BYTES" > "$WORK/io.json"
"$DRIVER" io-baseline "$WORK/in.ply" "$WORK" "$IN_BYTES" >> "$WORK/io.json"
IO_SECONDS=$(/usr/bin/python3 -c "import json; print(min(json.loads(l)['seconds'] for l in open('$WORK/io.json')))")

ROWS=()
for BUDGET in "${BUDGETS[@]}"; do
  echo "re-encode at --mem-budget $BUDGET..." >&2
  "$DRIVER" reencode "$WORK/in.ply" "$WORK/out.ply" --mem-budget "$BUDGET" --scratch "$WORK" \
    --report "$WORK/report-$BUDGET.json" --quiet --scratch-codec "${SCRATCH_CODEC:-auto}"
  rm -f "$WORK/out.ply"
  LOAD=$(cut -d' ' -f1 /proc/loadavg)
  MOVED=$(/usr/bin/python3 -c "import json; r = json.load(open('$WORK/report-$BUDGET.json')); print(r['output_bytes'], r['scratch_bytes_written'], r['scratch_bytes_read'])")
  # shellcheck disable=SC2086
  "$DRIVER" io-baseline "$WORK/in.ply" "$WORK" $MOVED > "$WORK/io-$BUDGET.json"
  # shellcheck disable=SC2086
  "$DRIVER" io-baseline "$WORK/in.ply" "$WORK" $MOVED >> "$WORK/io-$BUDGET.json"
  ROWS+=("$(/usr/bin/python3 - "$WORK/report-$BUDGET.json" "$BUDGET" "$IO_SECONDS" "$LOAD" "${CSV:-}" "$WORK/io-$BUDGET.json" <<'PY'
import json, os, sys
r = json.load(open(sys.argv[1]))
budget, io, load, csv = sys.argv[2], float(sys.argv[3]), sys.argv[4], sys.argv[5]
io_all = min(json.loads(line)["seconds_with_scratch"] for line in open(sys.argv[6]))
wall = r["wall_seconds"]
peak = r["peak_rss_bytes"] / 2**20
ok = "yes" if r["peak_rss_bytes"] <= r["budget_bytes"] else "**NO**"
mbps = (r["input_bytes"] + r["output_bytes"]) / wall / 1e6
pct = lambda s: 100 * s / wall if wall else 0
overlap = 100 * r["overlap_seconds"] / r["io_busy_seconds"] if r["io_busy_seconds"] else 0
mode = "out of core" if r["out_of_core_dereference"] else "resident"
blocks = "memory" if r.get("blocks_in_memory") else "scratch"
sw, sr = r["scratch_bytes_written"] / 1e9, r["scratch_bytes_read"] / 1e9
print(f"| {budget} | {r['output_faces']:,} | {mode} | {blocks} | {wall:.1f} | {peak:.0f} | {ok} | {mbps:.0f} | "
      f"{io:.2f} | {wall / io:.1f}x | {io_all:.2f} | {wall / io_all:.1f}x | {pct(r['io_busy_seconds']):.0f}% | "
      f"{pct(r['compute_busy_seconds']):.0f}% | {overlap:.0f}% | {r['cpu_seconds']:.1f} | {r['scratch_codec']} | "
      f"{sw:.2f} | {sr:.2f} | {load} |")
if csv:
    header = not os.path.exists(csv)
    with open(csv, "a") as f:
        if header:
            f.write("budget,faces,dereference,blocks,wall_s,peak_rss_mib,rss_le_budget,mb_per_s,io_floor_s,vs_io_floor,"
                    "io_floor_with_scratch_s,vs_io_floor_with_scratch,io_busy_pct,compute_busy_pct,overlap_pct,cpu_s,"
                    "scratch_codec,scratch_written_gb,scratch_read_gb,load_avg\n")
        f.write(f"{budget},{r['output_faces']},{mode},{blocks},{wall:.2f},{peak:.0f},{ok.strip('*').lower()},{mbps:.0f},"
                f"{io:.2f},{wall / io:.2f},{io_all:.2f},{wall / io_all:.2f},{pct(r['io_busy_seconds']):.0f},"
                f"{pct(r['compute_busy_seconds']):.0f},{overlap:.0f},{r['cpu_seconds']:.2f},{r['scratch_codec']},"
                f"{sw:.2f},{sr:.2f},{load}\n")
PY
)")
done

echo
echo "Input: $FACES faces, $(( IN_BYTES / 1000000 )) MB binary PLY; $(nproc) cores; load average $(cut -d' ' -f1 /proc/loadavg) at the end."
echo "I/O floor (read input + write the same bytes on the I/O thread alone): ${IO_SECONDS} s;"
echo "with scratch: the same plus writing and reading back the run's scratch bytes."
echo
echo "| budget | faces | dereference | blocks | wall s | peak RSS MiB | RSS <= budget | MB/s in+out | I/O floor s | vs I/O floor | floor with scratch s | vs floor with scratch | I/O busy | compute busy | overlap | CPU s | scratch codec | scratch written GB | scratch read GB | load avg |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
printf '%s\n' "${ROWS[@]}"
