#!/usr/bin/env python3
"""Per-pass patch phases of an out-of-core run, from its --trace.

    bench/trace_passes.py TRACE.json > passes.csv

One CSV row per pass over the patches (an out-of-core epoch, or the exact cut's pass):
its wall seconds (first span's start to last span's end), the seconds of each patch
phase summed over its patches (gather, build, setup, first_round, rounds, summary,
extract, export: the report's patch_phases, split by pass), and how many patches it
exported. Phase spans are never thinned (engine/trace.hpp), so the sums are whole even
when the trace's fine events were sampled. A pass starts where a patch is gathered
again after its export in the pass before (a patch run as several parts would look
like a new pass: the report's patch_splits says whether any was).
"""
import collections
import json
import sys

PHASES = ["gather", "build", "setup", "first_round", "rounds", "summary", "extract", "export"]


def main(path):
    trace = json.load(open(path))
    events = trace["traceEvents"] if isinstance(trace, dict) else trace
    spans = sorted((e for e in events if e.get("ph") == "X" and e["name"] in PHASES), key=lambda e: e["ts"])
    passes, exported = [], set()
    for e in spans:
        patch = e["args"].get("patch")
        if not passes or (e["name"] == "gather" and patch in exported):
            passes.append(collections.defaultdict(float, start=e["ts"]))
            exported = set()
        cur = passes[-1]
        cur[e["name"]] += e["dur"] / 1e6
        cur["end"] = e["ts"] + e["dur"]
        if e["name"] == "export":
            exported.add(patch)
            cur["patches"] += 1
    print("pass,wall_s," + ",".join(f"{p}_s" for p in PHASES) + ",patches")
    for i, p in enumerate(passes):
        wall = (p["end"] - p["start"]) / 1e6
        print(f"{i + 1},{wall:.1f}," + ",".join(f"{p[name]:.1f}" for name in PHASES) + f",{int(p['patches'])}")
    other = trace.get("otherData", {}) if isinstance(trace, dict) else {}
    if other:
        print(f"trace: {other}", file=sys.stderr)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
