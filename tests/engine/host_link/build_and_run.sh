#!/bin/bash
# Builds a host program against the engine's static library as a host would, then runs
# it: build_and_run.sh CXX SOURCE_ROOT ENGINE_LIB HOST_SOURCE OUT [FLAGS...]
# Exit 77 (skipped) when FLAGS cannot build even an empty program (no sanitizer runtime).
set -u
cxx=$1 root=$2 lib=$3 src=$4 out=$5
shift 5
if [ $# -gt 0 ]; then
  echo 'int main() { return 0; }' > "$out.probe.cpp"
  if ! "$cxx" "$@" "$out.probe.cpp" -o "$out.probe" 2>/dev/null; then
    echo "skip: $cxx cannot build with $*"
    exit 77
  fi
fi
if ! "$cxx" -std=c++20 -O1 "$@" -I"$root" "$src" "$lib" -o "$out"; then
  echo "FAIL: the host does not link against $lib"
  exit 1
fi
"$out" || { echo "FAIL: the host exits $?"; exit 1; }
echo ok
