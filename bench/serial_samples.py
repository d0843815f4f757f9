#!/usr/bin/env python3
"""Where a run leaves a core idle: the CPU samples taken while no other busy thread ran.

On a 2-core machine a run at 1.8 cores spends a tenth of its wall time with one thread
alone; which functions run then is what parallel work would save. perf samples every
busy thread at a fixed rate, so a sample with no sample of the other main thread within
1.5 periods was taken while that thread was not running.

    perf record -F 997 -o perf.data build/apps/qemflow simplify in.ply out.ply --ratio 0.01 --mem-budget 512M
    perf script -i perf.data -F tid,time,ip,sym > samples.txt
    bench/serial_samples.py samples.txt [TOP]

Prints the total and the alone samples, then the TOP symbols (default 30) by alone
samples, each with its total (symbols' argument lists cut; qemflow::nodes:: dropped).
The two threads with the most samples are the main threads (the job's and TBB's worker
on 2 cores); the I/O thread's samples are left out, and it counts as not running.
"""
import bisect
import re
import sys
from collections import Counter, defaultdict

PERIOD_WINDOW = 0.0015  # seconds either side: 1.5 sampling periods at -F 997


def read_samples(path):
    samples = []
    for line in open(path):
        m = re.match(r"\s*(\d+)\s+([\d.]+):\s*[0-9a-f]+\s*(.*)$", line)
        if not m:
            continue
        sym = m.group(3).strip().replace("(anonymous namespace)", "anon")
        sym = re.sub(r"\(.*", "", sym)[:110] if sym else "?"
        samples.append((float(m.group(2)), int(m.group(1)), sym.replace("qemflow::nodes::", "")))
    samples.sort()
    return samples


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    samples = read_samples(sys.argv[1])
    top = int(sys.argv[2]) if len(sys.argv) > 2 else 30
    per_thread = Counter(tid for _, tid, _ in samples)
    main_threads = [tid for tid, _ in per_thread.most_common(2)]
    times = defaultdict(list)
    for t, tid, _ in samples:
        times[tid].append(t)

    def other_ran(t, tid):
        for other in main_threads:
            if other == tid:
                continue
            ts = times[other]
            i = bisect.bisect_left(ts, t - PERIOD_WINDOW)
            if i < len(ts) and ts[i] <= t + PERIOD_WINDOW:
                return True
        return False

    alone, total = Counter(), Counter()
    for t, tid, sym in samples:
        if tid not in main_threads:
            continue
        total[sym] += 1
        if not other_ran(t, tid):
            alone[sym] += 1
    n, n_alone = sum(total.values()), sum(alone.values())
    print(f"samples {n}, alone {n_alone} ({100 * n_alone / max(n, 1):.1f}%)")
    for sym, c in alone.most_common(top):
        print(f"{c:6d} alone of {total[sym]:6d}  {sym}")


if __name__ == "__main__":
    main()
