#!/usr/bin/python3
"""Plots of the islands scheme's work from a run directory (dem.scheme = "islands"):

  1. the fraction of particles on the fine step per output interval (diagnostics.csv column
     fine_leaf_fraction) and the mean local steps per particle per sub-iteration
     (leaf_steps_mean), against time;
  2. the island size distribution over the run (run.json island_sizes: islands of each size,
     one count per island per sub-iteration; size 1 = a lone particle);
  3. the distribution over particles of the fraction of sub-iterations each spent in a fine
     island (run.json fine_fraction_per_particle: mean and percentiles).

usage: tools/plot_islands.py RUN_DIR [--out FILE.png]
"""
import argparse
import csv
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir")
    ap.add_argument("--out", default=None, help="PNG path (default RUN_DIR/islands.png)")
    a = ap.parse_args()
    try:
        with open(os.path.join(a.run_dir, "run.json")) as f:
            js = json.load(f)
        with open(os.path.join(a.run_dir, "diagnostics.csv")) as f:
            rows = list(csv.DictReader(f))
    except (OSError, json.JSONDecodeError) as e:
        sys.exit(f"plot_islands.py: cannot read {a.run_dir}: {e}")
    if js.get("scheme") != "islands" or "island_sizes" not in js:
        sys.exit(f"plot_islands.py: {a.run_dir} is not a run of the islands scheme "
                 f"(run.json scheme = {js.get('scheme')!r})")
    t = [1e3 * float(r["time"]) for r in rows[1:]]
    fine = [float(r["fine_leaf_fraction"]) for r in rows[1:]]
    steps = [float(r["leaf_steps_mean"]) for r in rows[1:]]

    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(15, 4.2))
    ax1.plot(t, fine, "b-", label="particles on the fine step")
    ax1.set_xlabel("t [ms]")
    ax1.set_ylabel("fraction of particles", color="b")
    ax1b = ax1.twinx()
    ax1b.plot(t, steps, "r--", label="local steps per particle per sub-iteration")
    ax1b.set_ylabel("mean local steps per sub-iteration", color="r")
    ax1.set_title("work per output interval")

    sizes = js["island_sizes"]
    labels = list(sizes)
    ax2.bar(range(len(labels)), [sizes[k] for k in labels], color="gray")
    ax2.set_xticks(range(len(labels)))
    ax2.set_xticklabels(labels, rotation=45)
    ax2.set_yscale("log")
    ax2.set_xlabel("island size (particles)")
    ax2.set_ylabel("islands (summed over sub-iterations)")
    ax2.set_title("island size distribution")

    d = js.get("fine_fraction_per_particle", {})
    keys = ["min", "p10", "p50", "p90", "p99", "max"]
    ax3.bar(range(len(keys)), [d.get(k, 0.0) for k in keys], color="teal")
    ax3.axhline(d.get("mean", 0.0), color="k", lw=1, label=f"mean {d.get('mean', 0.0):.4f}")
    ax3.set_xticks(range(len(keys)))
    ax3.set_xticklabels(keys)
    ax3.set_ylabel("fraction of sub-iterations in a fine island")
    ax3.set_title("per particle (percentiles over particles)")
    ax3.legend()
    fig.suptitle(f"{js.get('scene', '')}: islands, dt_sp = {js.get('dt_sp', 0):.3g} s")
    fig.tight_layout()
    out = a.out or os.path.join(a.run_dir, "islands.png")
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()
