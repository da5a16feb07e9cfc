#!/usr/bin/python3
"""Fluidized-bed validation: the time-averaged pressure drop at steady state equals the bed's
buoyant weight per unit area (the box's cross-section, or a cylinder's pi R^2) plus the gas head
(docs/theory.md §6):

    dp = N m g (1 - rho_g/rho_p) / A + rho_g g L          (20.04 + 0.10 Pa for the paper's bed)

Too slow for CI (a bed needs ~0.1 s of simulated time, ~10^3 fluid steps), so it is a script:
it runs cfddem on scenes/fluidized_bed.toml (or a smaller bed given by overrides), or reads an
existing run directory, averages the diagnostics column pressure_drop over [--from, end] and
compares. The expected value is computed from the run's resolved configuration (run.json).

usage:
  tools/fluidized_bed_check.py --run-dir runs/fluidized_bed [--from 0.05] [--tol 0.05]
  tools/fluidized_bed_check.py --small [--cfddem build/bin/cfddem] [--out /tmp/bed_small]
      --small: a quarter-section bed (0.8 x 10 x 0.8 mm, 2,500 particles, 16 x 50 x 16 cells,
      the same cells, gas and inflow as the paper's bed) for 0.1 s.
Exit status: 0 within tolerance, 1 outside it, 2 unreadable input.
"""
import argparse
import csv
import json
import math
import os
import subprocess
import sys

SMALL = ["domain.hi=[0.8e-3,1.0e-2,0.8e-3]", "particles.count=2500",
         "particles.region_hi=[0.8e-3,5.4e-3,0.8e-3]", "fluid.cells=[16,50,16]",
         "run.end_time=0.1", "output.interval=1e-3", "name=fluidized_bed_small"]


def toml_value(text):
    if not isinstance(text, str):  # run.json holds typed values since issue 17
        return text
    text = text.strip()
    if text.startswith("["):
        try:
            return [float(v) for v in text.strip("[]").split(",")]
        except ValueError:
            return text
    if text.startswith('"'):
        return text.strip('"')
    try:
        return float(text)
    except ValueError:
        return text


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--run-dir")
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--cfddem", default="build/bin/cfddem")
    ap.add_argument("--scene", default="scenes/fluidized_bed.toml")
    ap.add_argument("--out", default="/tmp/fluidized_bed_check")
    ap.add_argument("--threads", default="1")
    ap.add_argument("--from", dest="t_from", type=float, default=None,
                    help="average from this time (default: the second half of the run)")
    ap.add_argument("--tol", type=float, default=0.05)
    a = ap.parse_args()
    run_dir = a.run_dir
    if run_dir is None:
        cmd = [a.cfddem, "run", a.scene, "--threads", a.threads, "--out", a.out, "--overwrite"]
        if a.small:
            cmd += SMALL
        print("running:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)
        run_dir = a.out
    try:
        cfg = {k: toml_value(v) for k, v in
               json.load(open(os.path.join(run_dir, "run.json")))["configuration"].items()}
        rows = list(csv.DictReader(open(os.path.join(run_dir, "diagnostics.csv"))))
    except (OSError, KeyError, ValueError) as e:
        print(f"fluidized_bed_check: cannot read {run_dir}: {e}", file=sys.stderr)
        return 2
    lo, hi = cfg["domain.lo"], cfg["domain.hi"]
    g = cfg["gravity"]
    axis = max(range(3), key=lambda k: abs(g[k]))
    area = 1.0
    for k in range(3):
        if k != axis:
            area *= hi[k] - lo[k]
    if cfg.get("domain.shape") == "cylinder":  # a round column: its cross-section pi R^2
        area = math.pi * cfg["domain.cylinder_radius"] ** 2
    n, d, rho_p = cfg["particles.count"], cfg["particles.diameter"], cfg["particles.density"]
    rho_g = cfg["fluid.density"]
    m = rho_p * math.pi * d ** 3 / 6
    bed = n * m * abs(g[axis]) * (1 - rho_g / rho_p) / area
    head = rho_g * abs(g[axis]) * (hi[axis] - lo[axis])
    t = [float(r["time"]) for r in rows]
    t_from = a.t_from if a.t_from is not None else 0.5 * t[-1]
    sel = [float(r["pressure_drop"]) for r, ti in zip(rows, t) if ti >= t_from]
    if not sel:
        print("fluidized_bed_check: no rows in the averaging window", file=sys.stderr)
        return 2
    mean = sum(sel) / len(sel)
    sd = math.sqrt(sum((v - mean) ** 2 for v in sel) / max(1, len(sel) - 1))
    expect = bed + head
    err = mean / expect - 1
    print(f"bed buoyant weight / area {bed:.4f} Pa + gas head {head:.4f} Pa = {expect:.4f} Pa")
    print(f"time-averaged pressure_drop over [{t_from:.4g}, {t[-1]:.4g}] s ({len(sel)} rows): "
          f"{mean:.4f} Pa (row std {sd:.3f} Pa), error {100 * err:+.2f}% (tolerance "
          f"{100 * a.tol:.1f}%)")
    return 0 if abs(err) <= a.tol else 1


if __name__ == "__main__":
    sys.exit(main())
