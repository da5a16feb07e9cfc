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

A scene too large to run here is priced from a smaller one (--grow riser_1e7=riser_1e6:riser_1e5:10):
each count of the riser_1e6 runs, per rank, is continued along its measured trend with N
(the exponent between riser_1e5 and riser_1e6 at the same rank count; scaling_model.grow), and
the grown counts are priced as a run would be (rows of predicted.csv under the new name).
--grow-check riser_1e6=riser_1e5:riser_1e4:10 tests that extrapolation where the answer is
known: the trend from riser_1e4 to riser_1e5 grows the riser_1e5 runs to 1e6, and grow_check.csv
sets each count and the predicted efficiencies beside those of the measured riser_1e6 runs.

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


def calibration_runs(cals, alias, scene, scheme):
    """(calibration scene, its runs by rank count): the scene's own 1-rank runs first,
    --calibrate-with's scene only where it has none."""
    cal_scene = scene if 1 in cals.get((scene, scheme), {}) else alias.get(scene, scene)
    return cal_scene, cals.get((cal_scene, scheme), {})


def grown(counts, big, small, factor):
    """{scheme: {ranks: (grown run, trend rank count, exponents)}}: each R-rank run of scene `big`
    grown `factor` times along the trend of its counts from scene `small` (count_maxima of the
    median runs at the same rank count, or at the nearest in log R that both scenes have)."""
    out = {}
    for (scene, scheme), by_r in counts.items():
        if scene != big:
            continue
        pairs = [r for r in counts.get((small, scheme), {}) if r > 1 and r in by_r]
        for r in sorted(q for q in by_r if q > 1):
            if not pairs:
                break
            q = min(pairs, key=lambda q: abs(math.log(q / r)))
            s_run, b_run = median_run(counts[(small, scheme)][q]), median_run(by_r[q])
            e = scaling_model.trend_exponents(scaling_model.count_maxima(s_run),
                                              scaling_model.count_maxima(b_run),
                                              s_run["particles"], b_run["particles"])
            out.setdefault(scheme, {})[r] = (scaling_model.grow(median_run(by_r[r]), factor, e),
                                             q, e)
    return out


def grow_check(specs, counts, cals, alias, a):
    """--grow-check BIG=MID:SMALL:F: MID's runs grown by F along the SMALL -> MID trend, against
    BIG's measured runs at the same rank count: each count's maximum per fluid step, and the
    model's strong efficiency at each of --cores from either."""
    rows = []
    for spec in specs:
        big, rest = spec.split("=", 1)
        mid, small, factor = rest.split(":")
        for scheme, by_r in sorted(grown(counts, mid, small, float(factor)).items()):
            measured_runs = counts.get((big, scheme), {})
            cal_runs = calibration_runs(cals, alias, big, scheme)[1]
            for r, (g, q, _) in sorted(by_r.items()):
                if r not in measured_runs:
                    continue
                measured = median_run(measured_runs[r])
                mm, gm = scaling_model.count_maxima(measured), scaling_model.count_maxima(g)
                row = {"scene": big, "scheme": scheme, "ranks": r,
                       "grown_from": f"{mid} along {small}->{mid} at {q} ranks"}
                for f in scaling_model.COUNT_FIELDS:
                    row[f"{f}_error"] = (gm[f] - mm[f]) / mm[f] if mm[f] > 0 else 0.0
                if 1 in cal_runs:
                    cal = scaling_model.calibrate(median_run(cal_runs[1]))
                    for c in a.cores:
                        for name, run in (("measured", measured), ("grown", g)):
                            row[f"eff_{c}_{name}"] = scaling_model.predict(
                                run, cal, c, False, a.network, a.cores_per_node)[1]
                rows.append(row)
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
    ap.add_argument("--grow", action="append", default=[], metavar="NEW=BIG:SMALL:F",
                    help="price scene NEW, F times BIG's particles, from BIG's runs grown along "
                         "the count trend from SMALL to BIG")
    ap.add_argument("--grow-check", action="append", default=[], metavar="BIG=MID:SMALL:F",
                    help="grow MID's runs by F along the SMALL-to-MID trend and set them beside "
                         "BIG's measured runs (grow_check.csv)")
    a = ap.parse_args()
    alias = dict(kv.split("=", 1) for kv in a.calibrate_with)
    counts, cals = collect(a.counts_dir), collect(a.calibration_dir)
    grown_runs = {}  # (scene, scheme) -> {ranks: [grown run]}, priced below like measured ones
    grow_notes = []
    for spec in a.grow:
        new, rest = spec.split("=", 1)
        big, small, factor = rest.split(":")
        for scheme, by_r in grown(counts, big, small, float(factor)).items():
            for r, (g, q, e) in sorted(by_r.items()):
                grown_runs.setdefault((new, scheme), {})[r] = [g]
                grow_notes.append({"scene": new, "scheme": scheme, "from": big, "ranks": r,
                                   "trend": f"{small}->{big} at {q} ranks",
                                   **{f"e_{k}": v for k, v in e.items()}})
        alias.setdefault(new, alias.get(big, big))
    if not counts:
        sys.exit(f"scaling_model_sweep.py: no <scene>_<scheme>_r<R>/run.json in {a.counts_dir}")
    os.makedirs(a.out, exist_ok=True)
    count_table, predicted, checks = [], [], []
    curves = {"strong": [], "weak": []}
    for (scene, scheme), by_r in sorted({**counts, **grown_runs}.items()):
        runs = [median_run(by_r[r]) for r in sorted(by_r) if r > 1]
        if (scene, scheme) not in grown_runs:
            for run in runs:
                count_table.append({"scene": scene, "scheme": scheme,
                                    **scaling_model.count_rows(run)})
        cal_scene, cal_runs = calibration_runs(cals, alias, scene, scheme)
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
    checks_g = grow_check(a.grow_check, counts, cals, alias, a)
    if checks_g:
        write_csv(os.path.join(a.out, "grow_check.csv"), checks_g)
    if grow_notes:
        write_csv(os.path.join(a.out, "grown.csv"), grow_notes)
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
