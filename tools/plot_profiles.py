#!/usr/bin/python3
"""Profiles along the column from a run directory's profiles.csv (output.profile_axis and
output.profile_bins in the scene):

  1. a heat map of the solids fraction against position along the axis and time;
  2. line plots of the solids fraction against position at a few times (first, last and evenly
     spaced between), the way a bed's or riser's axial profile is usually shown;
  3. the same line plots for a second column (--column, default the particles' mean velocity
     along the profile axis; with a gas e.g. eps_g, pressure or slip_y).

usage: tools/plot_profiles.py RUN_DIR [--column NAME] [--lines N] [--out FILE.png]
"""
import argparse
import csv
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def read_profiles(run_dir):
    """times (sorted), centres, and {column: 2-D array [time, bin]} from profiles.csv."""
    path = os.path.join(run_dir, "profiles.csv")
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path} has no rows")
    times = sorted({float(r["time"]) for r in rows})
    bins = sorted({int(float(r["bin"])) for r in rows})
    t_index = {t: k for k, t in enumerate(times)}
    centres = [0.0] * len(bins)
    data = {c: np.full((len(times), len(bins)), np.nan) for c in rows[0] if c not in ("time", "bin", "centre")}
    for r in rows:
        k, b = t_index[float(r["time"])], int(float(r["bin"]))
        centres[b] = float(r["centre"])
        for c in data:
            data[c][k, b] = float(r[c])
    return np.array(times), np.array(centres), data


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir")
    ap.add_argument("--column", default=None, help="second quantity to plot (a profiles.csv column)")
    ap.add_argument("--lines", type=int, default=5, help="how many times to draw as lines (>= 1)")
    ap.add_argument("--out", default=None, help="PNG path (default RUN_DIR/profiles.png)")
    a = ap.parse_args()
    if a.lines < 1:
        sys.exit("plot_profiles.py: --lines must be >= 1")
    try:
        times, centres, data = read_profiles(a.run_dir)
    except (OSError, ValueError, KeyError) as e:
        sys.exit(f"plot_profiles.py: cannot read the profiles of {a.run_dir}: {e} "
                 "(set output.profile_axis and output.profile_bins in the scene)")
    axis = "y"
    try:
        with open(os.path.join(a.run_dir, "run.json")) as f:
            axis = json.load(f).get("config", {}).get("output.profile_axis", "y").strip('"')
    except (OSError, json.JSONDecodeError):
        pass
    second = a.column or f"vp_{axis}"
    if second not in data:
        sys.exit(f"plot_profiles.py: no column {second!r} in profiles.csv (it has: {', '.join(data)})")

    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(15, 4.2))
    t_ms = 1e3 * times
    h = centres[1] - centres[0] if len(centres) > 1 else 1.0
    extent = [t_ms[0], t_ms[-1] if len(t_ms) > 1 else t_ms[0] + 1.0, centres[0] - h / 2, centres[-1] + h / 2]
    im = ax1.imshow(data["solids_fraction"].T, origin="lower", aspect="auto", extent=extent, cmap="viridis")
    fig.colorbar(im, ax=ax1, label="solids fraction")
    ax1.set_xlabel("t [ms]")
    ax1.set_ylabel(f"{axis} [m]")
    ax1.set_title("solids fraction along the column")

    picks = sorted({int(round(k)) for k in np.linspace(0, len(times) - 1, min(a.lines, len(times)))})
    for k in picks:
        label = f"t = {t_ms[k]:.3g} ms"
        ax2.plot(data["solids_fraction"][k], centres, label=label)
        ax3.plot(data[second][k], centres, label=label)
    ax2.set_xlabel("solids fraction")
    ax2.set_ylabel(f"{axis} [m]")
    ax2.set_title("solids fraction profiles")
    ax2.legend(fontsize=8)
    ax3.set_xlabel(second)
    ax3.set_ylabel(f"{axis} [m]")
    ax3.set_title(f"{second} profiles")
    fig.tight_layout()
    out = a.out or os.path.join(a.run_dir, "profiles.png")
    fig.savefig(out, dpi=120)
    finite = data["solids_fraction"][np.isfinite(data["solids_fraction"])]
    print(f"wrote {out}: {len(times)} times x {len(centres)} bins, solids fraction "
          f"{finite.min() if finite.size else math.nan:.4g}..{finite.max() if finite.size else math.nan:.4g}")


if __name__ == "__main__":
    main()
