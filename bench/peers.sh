#!/usr/bin/env bash
# Side-by-side benchmark of `qemflow simplify --in-core` against meshoptimizer
# (meshopt_simplify) and OpenMesh's greedy Decimater (ModQuadricT), at 1% and 0.1%.
# Per run: wall and CPU seconds, peak RSS (/usr/bin/time), input faces per CPU second,
# bytes of peak RSS per input face, and `qemflow compare` errors (relative to the
# bounding-box diagonal). Writes bench/results/peers.csv.
#
#   bench/peers.sh [BUILD_DIR]         (default build/)
# Environment: PEERS_MESHES  space-separated list of mesh paths and gen:FACES entries
#                            (default: the Stanford dragon, igea, gen:1M, gen:20M)
#              PEERS_TOOLS   default "qemflow meshopt openmesh"; also qemflow-fast,
#                            qemflow with --charge-from 2 (the deviation charge only in
#                            the last stretch: nodes/decimate/README.md)
#              PEERS_RATIOS  default "0.01 0.001"
#              PEERS_CSV     output file (default bench/results/peers.csv)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(dirname "$here")"
build="${1:-$repo/build}"
qemflow="$build/apps/qemflow"
work="$(mktemp -d /tmp/qemflow-peers.XXXXXX)"
trap 'rm -rf "$work"' EXIT
mkdir -p "$here/results"
out="${PEERS_CSV:-$here/results/peers.csv}"

# The peer tool links OpenMesh's Decimater and meshoptimizer, which the library does not
# need: CMake builds build/bench/peer_simplify only when it finds meshoptimizer, so this
# script compiles its own copy against BUILD_DIR's io library.
peer="$work/peer_simplify"
g++ -std=c++20 -O2 -DNDEBUG -I"$repo" "$here/peers/peer_simplify.cpp" "$build/io/libqemflow_io.a" \
  -lOpenMeshTools -lOpenMeshCore -lmeshoptimizer -lzstd -o "$peer"

meshes="${PEERS_MESHES:-$repo/../shared/data/stanford-dragon.ply.zst $repo/../shared/data/igea.ply.zst gen:1M gen:20M}"
tools="${PEERS_TOOLS:-qemflow meshopt openmesh}"
ratios="${PEERS_RATIOS:-0.01 0.001}"

echo "mesh,tool,ratio,input_faces,output_faces,wall_s,cpu_s,input_faces_per_cpu_s,peak_rss_bytes,rss_bytes_per_input_face,rms_rel,hausdorff_rel,flipped_faces" > "$out"
for mesh in $meshes; do
  if [[ "$mesh" == gen:* ]]; then
    faces="${mesh#gen:}"
    path="$work/blob-$faces.ply"
    "$qemflow" gen "$path" --faces "$faces" --shape blob --quiet
    name="blob-$faces"
  else
    path="$mesh"
    name="$(basename "$mesh" .ply.zst)"
  fi
  for ratio in $ratios; do
    for tool in $tools; do
      result="$work/$name-$tool-$ratio.ply"
      timing="$work/time.txt"
      if [[ "$tool" == qemflow* ]]; then
        extra=()
        [[ "$tool" == qemflow-fast ]] && extra=(--charge-from 2)
        /usr/bin/time -f "%e %U %S %M" -o "$timing" \
          "$qemflow" simplify "$path" "$result" --ratio "$ratio" --in-core --quiet \
          --report "$work/report.json" "${extra[@]}"
        input_faces=$(python3 -c "import json;print(json.load(open('$work/report.json'))['input_faces'])")
      else
        /usr/bin/time -f "%e %U %S %M" -o "$timing" \
          "$peer" "$tool" "$path" "$result" --ratio "$ratio" > "$work/peer.txt"
        input_faces=$(awk '{print $3}' "$work/peer.txt")
      fi
      read -r wall user sys rss_kb < "$timing"
      "$qemflow" compare "$path" "$result" --json > "$work/compare.json"
      python3 - "$work/compare.json" "$name" "$tool" "$ratio" "$input_faces" "$wall" "$user" "$sys" "$rss_kb" >> "$out" <<'PY'
import json, sys
c = json.load(open(sys.argv[1]))
name, tool, ratio, faces, wall, user, sys_s, rss_kb = sys.argv[2:]
faces = int(faces); cpu = float(user) + float(sys_s); rss = int(rss_kb) * 1024
sym = {k: (v if v is not None else float("nan")) for k, v in c["distances"]["symmetric"]["relative"].items()}
out_faces = c["topology"]["simplified"].get("faces", c["topology"]["simplified"].get("triangles", ""))
print(f"{name},{tool},{ratio},{faces},{out_faces},{wall},{cpu:.2f},{faces / cpu:.0f},{rss},{rss / faces:.1f},"
      f"{sym['rms']:.3e},{sym['hausdorff']:.3e},{c['flipped_faces']}")
PY
      tail -1 "$out"
      rm -f "$result"
    done
  done
done
echo "wrote $out"
