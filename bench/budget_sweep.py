"""Plots bench/budget_sweep.sh's CSV: faces/s and peak RSS against --mem-budget."""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

rows = sorted(csv.DictReader(open(sys.argv[1])), key=lambda r: int(r["budget_bytes"]))
budget = [int(r["budget_bytes"]) / 2**20 for r in rows]
speed = [float(r["faces_per_s"]) / 1e3 for r in rows]
# Wall time follows the load of a shared machine; faces per CPU-second much less.
speed_cpu = [float(r["faces_per_s"]) * float(r["wall_s"]) / float(r["cpu_s"]) / 1e3 for r in rows]
peak = [int(r["peak_rss_bytes"]) / 2**20 for r in rows]
fig, ax = plt.subplots(figsize=(7, 4))
ax.plot(budget, speed, "o-", color="tab:blue", label="input faces per wall second (k)")
ax.plot(budget, speed_cpu, "^-.", color="tab:cyan", label="input faces per CPU second (k)")
ax.set_xscale("log", base=2)
ax.set_xlabel("--mem-budget (MiB)")
ax.set_ylabel("thousand input faces per second", color="tab:blue")
ax.set_ylim(bottom=0)
ax2 = ax.twinx()
ax2.plot(budget, peak, "s--", color="tab:red", label="peak RSS")
ax2.plot(budget, budget, ":", color="gray", label="budget")
ax2.set_yscale("log", base=2)
ax2.set_ylabel("peak RSS (MiB)", color="tab:red")
ax.set_title(f"qemflow simplify --ratio 0.01, {rows[0]['faces'] if rows else ''} faces")
fig.legend(loc="upper left", bbox_to_anchor=(0.12, 0.88))
fig.tight_layout()
fig.savefig(sys.argv[2], dpi=120)
