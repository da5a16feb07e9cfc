#!/usr/bin/python3
"""The sub-iteration length an islands run with dem.nsubit = "auto" chose, against time, from its
run.json (nsubit_choices: a row per change, chosen at the end of a control interval for the next
ones, with the bounds, the model's fine-particle estimate and the reason): dt_sp (left axis, log)
and nsubit per control interval (right axis) as steps, one line per run directory given, and the
table of choices printed.

usage: tools/plot_nsubit.py RUN_DIR [RUN_DIR ...] [--out FILE.png] [--quiet]
"""
import argparse
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def load(run_dir):
    try:
        with open(os.path.join(run_dir, "run.json")) as f:
            js = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        sys.exit(f"plot_nsubit.py: cannot read {run_dir}/run.json: {e}")
    if js.get("nsubit") != "auto" or "nsubit_choices" not in js:
        sys.exit(f"plot_nsubit.py: {run_dir} is not an islands run with dem.nsubit = \"auto\" "
                 f"(run.json scheme = {js.get('scheme')!r}, nsubit = {js.get('nsubit')!r})")
    return js


def steps(js):
    """(t, dt_sp, nsubit) at each change, closed at the run's end."""
    rows = js["nsubit_choices"]
    t = [r["t"] for r in rows] + [js["end_time"]]
    dt = [r["dt_sp"] for r in rows] + [rows[-1]["dt_sp"]]
    n = [r["nsubit"] for r in rows] + [rows[-1]["nsubit"]]
    return t, dt, n


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dirs", nargs="+")
    ap.add_argument("--out", default=None, help="PNG path (default FIRST_RUN_DIR/nsubit.png)")
    ap.add_argument("--quiet", action="store_true", help="no table")
    a = ap.parse_args()
    runs = [(d, load(d)) for d in a.run_dirs]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax2 = ax.twinx()
    for d, js in runs:
        t, dt, n = steps(js)
        label = os.path.basename(os.path.normpath(d))
        ax.step([1e3 * x for x in t], dt, where="post", label=f"{label}: dt_sp")
        ax2.step([1e3 * x for x in t], n, where="post", linestyle=":", alpha=0.6,
                 label=f"{label}: nsubit")
        ax.axhline(js["dt"], color="grey", linewidth=0.8)
        if not a.quiet:
            print(f"{d}: control interval {js['control_interval']:.4g} s, fine dt {js['dt']:.4g} s")
            print(f"{'t [s]':>12} {'nsubit':>7} {'dt_sp [s]':>11} {'kept':>5} {'min':>5} "
                  f"{'max':>5} {'fine est':>9} {'rho':>6}  reason")
            for r in js["nsubit_choices"]:
                print(f"{r['t']:12.6g} {r['nsubit']:7d} {r['dt_sp']:11.4g} {r['intervals']:5d} "
                      f"{r['nsubit_min']:5d} {r['nsubit_max']:5d} {r['fine_estimate']:9.3g} "
                      f"{r['rho']:6.3g}  {r['reason']}")
    ax.set_yscale("log")
    ax.set_xlabel("t [ms]")
    ax.set_ylabel("dt_sp [s] (grey: the fine step)")
    ax2.set_ylabel("sub-iterations per control interval")
    ax.set_title("islands, dem.nsubit = \"auto\": the chosen sub-iteration length")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=8, loc="best")
    fig.tight_layout()
    out = a.out or os.path.join(a.run_dirs[0], "nsubit.png")
    tmp = out + ".tmp.png"
    fig.savefig(tmp, dpi=120)
    os.replace(tmp, out)
    if not a.quiet:
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
