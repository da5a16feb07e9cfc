#!/usr/bin/python3
"""Plot columns of a cfddem diagnostics.csv against time (one panel per column), optionally for
several runs on the same axes.

  tools/plot_diagnostics.py runs/hcs/diagnostics.csv                     # T and E_kin
  tools/plot_diagnostics.py runs/*/diagnostics.csv -c granular_temperature --logy -o T.png
  tools/plot_diagnostics.py runs/hcs/diagnostics.csv --list               # column names
  tools/plot_diagnostics.py runs/hcs runs/hcs_islands                    # run directories
"""
import argparse
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def load(path):
    if os.path.isdir(path):  # a run directory: its diagnostics.csv
        path = os.path.join(path, "diagnostics.csv")
    if not os.path.isfile(path):
        sys.exit(f"{path}: no such file")
    data = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
    if data.dtype.names is None or "time" not in data.dtype.names:
        sys.exit(f"{path}: no 'time' column; is this a cfddem diagnostics.csv?")
    return data


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("csv", nargs="+", help="diagnostics.csv files or run directories")
    ap.add_argument("-c", "--columns", nargs="+",
                    default=["granular_temperature", "kinetic_energy"])
    ap.add_argument("-o", "--output", default="diagnostics.png")
    ap.add_argument("--logy", action="store_true")
    ap.add_argument("--list", action="store_true", help="print the column names and exit")
    a = ap.parse_args()
    runs = [(p, load(p)) for p in a.csv]
    if a.list:
        print("\n".join(runs[0][1].dtype.names))
        return
    for c in a.columns:
        for p, d in runs:
            if c not in d.dtype.names:
                sys.exit(f"{p}: no column '{c}' (have: {', '.join(d.dtype.names)})")
    fig, axes = plt.subplots(len(a.columns), 1, sharex=True, squeeze=False,
                             figsize=(6.4, 2.4 * len(a.columns) + 0.6))
    for ax, c in zip(axes[:, 0], a.columns):
        for p, d in runs:
            run_dir = p if os.path.isdir(p) else os.path.dirname(os.path.abspath(p))
            label = os.path.basename(os.path.abspath(run_dir)) or p
            ax.plot(d["time"], d[c], marker=".", label=label)
        ax.set_ylabel(c)
        if a.logy:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    if len(runs) > 1:
        axes[0, 0].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(a.output, dpi=150)
    print(a.output)


if __name__ == "__main__":
    main()
