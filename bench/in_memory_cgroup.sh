#!/usr/bin/env bash
# Runs a command in a fresh memory cgroup whose limit counts the page cache too, so that
# a mid-size run sees the page-cache pressure a 200M-face run has on this machine (its
# ~24 GB state does not fit the page cache; a 20M one's 2.3 GB does, unless limited).
# Needs root and a writable cgroup memory controller (v1 or v2).
#
#   bench/in_memory_cgroup.sh LIMIT CMD...
#   bench/in_memory_cgroup.sh 1700M build/apps/qemflow simplify g20.ply o.ply --ratio 0.01 \
#       --mem-budget 1G --in-core-faces 1000000 --report r.json
#
# On stderr at the end: the cgroup's peak usage and how often it hit its limit.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: $0 LIMIT CMD..." >&2; exit 2; }
LIMIT=$1
shift
if [ -f /sys/fs/cgroup/cgroup.controllers ]; then
  CG=/sys/fs/cgroup/qemflow-bench-$$
  mkdir "$CG"
  echo "$LIMIT" > "$CG/memory.max"
else
  CG=/sys/fs/cgroup/memory/qemflow-bench-$$
  mkdir "$CG"
  echo "$LIMIT" > "$CG/memory.limit_in_bytes"
fi
cleanup() {
  [ -f "$CG/memory.force_empty" ] && echo 1 > "$CG/memory.force_empty" 2>/dev/null || true
  rmdir "$CG" 2>/dev/null || true
}
trap cleanup EXIT
set +e
bash -c 'echo $$ > "$1/cgroup.procs"; shift; exec "$@"' -- "$CG" "$@"
RC=$?
set -e
if [ -f "$CG/memory.max_usage_in_bytes" ]; then
  echo "cgroup: peak $(( $(cat "$CG/memory.max_usage_in_bytes") >> 20 )) MiB of $LIMIT, hit its limit $(cat "$CG/memory.failcnt") times" >&2
elif [ -f "$CG/memory.peak" ]; then
  echo "cgroup: peak $(( $(cat "$CG/memory.peak") >> 20 )) MiB of $LIMIT" >&2
fi
exit $RC
