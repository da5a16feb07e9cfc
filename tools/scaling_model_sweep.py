#!/usr/bin/python3
"""The count tables and predicted curves of tools/scaling_model.py for a whole sweep at once.

Reads a folder of count runs named <scene>_<scheme>_r<R> (R-rank runs, 1 thread per rank, e.g.
made oversubscribed on two cores) and a folder of calibration runs named <scene>_<scheme>_r1
(1 rank, 1 thread), and writes to --out:

  counts.csv       scene, scheme and scaling_model.count_rows: per fluid step, the mean and max
                   over the ranks of each count in run.json's rank_counts
  predicted.csv    scene, scheme, mode (strong or weak), cores, efficiency, limiting term, the
                   rank count extrapolated from and each term's seconds (strong: from the
                   largest R <= P; weak: from the one run whose particles per rank are nearest
                   --weak-per-core, default 62,500, its work per rank held)
  predicted.png    the strong curves, one per scene and scheme, points marked with their
                   limiting term (predicted_weak.png: the weak ones)
  check.csv        the model against the measured loop time of the calibration folder's runs
                   at 1 rank (the per-core speeds against the spread of the repeats) and at 2
                   ranks (the whole model), medians of repeats named ..._r<R>_try<k>

A scene's calibration may come from a smaller scene of the same base (--calibrate-with
riser_1e6=riser_1e5): the per-core speeds are per particle step, pair and cell, and the serial
time is then the R-rank counts summed over the ranks (scaling_model.serial_seconds).

Usage:
  tools/scaling_model_sweep.py --counts-dir /tmp/h20/counts --calibration-dir /tmp/h20/cal \\
      --out tools/scaling_results/model --cores 16 256 4096
"""
import argparse
import csv
import math
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scaling_model  # noqa: E402

NAME = re.compile(r"^(?P<scene>.+)_(?P<scheme>explicit|orb|islands)_r(?P<ranks>\d+)"
                  r"(_try(?P<try>\d+))?$")


def median_run(runs):
    """Of repeated runs, the one with the median loop_seconds (the lower middle of an even
    count): one whole run, so its phases and counts stay consistent with each other."""
    runs = sorted(runs, key=lambda j: j["loop_seconds"])
    return runs[(len(runs) - 1) // 2]


def collect(folder):
    """{(scene, scheme): {ranks: [run.json, ...]}} of the finished runs in folder (repeats are
    named ..._r<R>_try<k>)."""
    out = {}
    for name in sorted(os.listdir(folder)):
        m = NAME.match(name)
        path = os.path.join(folder, name, "run.json")
        if not m or not os.path.isfile(path):
            continue
        by_r = out.setdefault((m["scene"], m["scheme"]), {})
        by_r.setdefault(int(m["ranks"]), []).append(scaling_model.load(path))
    return out


def check_rows(scene, scheme, cal_runs, cal, network, per_node):
    """The model against the measured repeats at each rank count of the calibration folder:
    1 rank checks the per-core speeds against the spread of the repeats, 2 ranks (and more)
    the whole model (compute, messages, reductions) against a real parallel run."""
    rows = []
    for r, runs in sorted(cal_runs.items()):
        meas = [j["loop_seconds"] / scaling_model.fluid_steps(j) for j in runs]
        run = median_run(runs)
        if r == 1:
            model = cal[3]
            lim = "-"
        else:
            model, _, lim, _ = scaling_model.predict(run, cal, r, True, network, per_node)
        med = run["loop_seconds"] / scaling_model.fluid_steps(run)
        rows.append({"scene": scene, "scheme": scheme, "ranks": r, "repeats": len(runs),
                     "measured_median_s_per_fluid_step": med, "measured_min_s": min(meas),
                     "measured_max_s": max(meas), "model_s_per_fluid_step": model,
                     "relative_error": (model - med) / med, "limiting_term": lim})
    return rows


def write_csv(path, rows):
    tmp = path + ".tmp"
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--counts-dir", required=True)
    ap.add_argument("--calibration-dir", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--cores", type=int, nargs="+", default=[16, 64, 256, 1024, 4096])
    ap.add_argument("--calibrate-with", action="append", default=[], metavar="SCENE=SCENE",
                    help="calibrate SCENE with the 1-rank runs of another scene where it has "
                         "none of its own")
    ap.add_argument("--weak-per-core", type=float, default=62500.0,
                    help="weak curves: the run whose particles per rank are nearest this")
    ap.add_argument("--network", choices=["auto", "shm", "ib"], default="auto")
    ap.add_argument("--cores-per-node", type=int, default=64)
    a = ap.parse_args()
    alias = dict(kv.split("=", 1) for kv in a.calibrate_with)
    counts, cals = collect(a.counts_dir), collect(a.calibration_dir)
    if not counts:
        sys.exit(f"scaling_model_sweep.py: no <scene>_<scheme>_r<R>/run.json in {a.counts_dir}")
    os.makedirs(a.out, exist_ok=True)
    count_table, predicted, checks = [], [], []
    curves = {"strong": [], "weak": []}
    for (scene, scheme), by_r in sorted(counts.items()):
        runs = [median_run(by_r[r]) for r in sorted(by_r) if r > 1]
        for run in runs:
            count_table.append({"scene": scene, "scheme": scheme, **scaling_model.count_rows(run)})
        # The scene's own 1-rank runs first; --calibrate-with only where there are none.
        cal_scene = scene if 1 in cals.get((scene, scheme), {}) else alias.get(scene, scene)
        cal_runs = cals.get((cal_scene, scheme), {})
        if 1 not in cal_runs:
            print(f"scaling_model_sweep.py: no calibration for {scene} {scheme}: counts only",
                  file=sys.stderr)
            continue
        cal = scaling_model.calibrate(median_run(cal_runs[1]))
        predicted_from = cal_scene
        if cal_scene == scene:
            checks += check_rows(scene, scheme, cal_runs, cal, a.network, a.cores_per_node)
        # Weak: one run throughout, the one whose particles per rank are nearest the target
        # (62,500 per core, issue 20's weak series), its per-rank work held at every P.
        weak_run = min(runs, key=lambda j: abs(math.log(
            j["particles"] / scaling_model.ranks_of(j) / a.weak_per_core)))
        for mode in ("strong", "weak"):
            pts = []
            for c in a.cores:
                run = weak_run if mode == "weak" else scaling_model.nearest_run(runs, c)
                total, eff, lim, terms = scaling_model.predict(run, cal, c, mode == "weak",
                                                               a.network, a.cores_per_node)
                pts.append((c, eff, lim))
                predicted.append({"scene": scene, "scheme": scheme, "calibration": predicted_from,
                                  "mode": mode, "cores": c,
                                  "efficiency": eff, "limiting_term": lim,
                                  "from_ranks": scaling_model.ranks_of(run),
                                  "model_s_per_fluid_step": total,
                                  **{k.replace(" ", "_") + "_s": v for k, v in terms.items()}})
            curves[mode].append((f"{scene} {scheme}", pts))
    write_csv(os.path.join(a.out, "counts.csv"), count_table)
    if checks:
        write_csv(os.path.join(a.out, "check.csv"), checks)
    if predicted:
        write_csv(os.path.join(a.out, "predicted.csv"), predicted)
        what = "model priced from counts at 2-64 ranks (1 thread per rank); network " + a.network
        scaling_model.plot(os.path.join(a.out, "predicted.png"), curves["strong"],
                           "strong scaling, " + what)
        scaling_model.plot(os.path.join(a.out, "predicted_weak.png"), curves["weak"],
                           f"weak scaling ({a.weak_per_core:g} particles per core), " + what)
    print(f"scaling_model_sweep.py: wrote {a.out}/counts.csv ({len(count_table)} rows)"
          + (f", predicted.csv ({len(predicted)} rows), predicted.png, predicted_weak.png"
             if predicted else "") + (f", check.csv ({len(checks)} rows)" if checks else ""))


if __name__ == "__main__":
    main()
