#!/usr/bin/python3
"""Speed/accuracy trade of the adaptive schemes (orb, islands), like the paper's Fig. "hcserr".

For a scene: one explicit reference run, then the orb scheme for every (nsubit, levels) of the
sweep (--schemes orb islands: also the islands scheme per nsubit). Runs are sequential (never two at once) so wall times are comparable within the sweep.

  error       = mean_t |O_orb(t) - O_ref(t)| / mean_t O_ref(t)   (the paper's definition; O is
                --observable, a diagnostics.csv column; the orb row at t is matched to the
                reference row at the same time, linear interpolation)
  speedup     = loop_seconds(explicit) / loop_seconds(orb)   (run.json, same sweep; with
                --repeat N the minimum of N runs of each; the contact census's census_seconds,
                the same work in every run, is taken off loop_seconds, and its share of the
                loop off the CPU time)
  cpu_speedup = the same with the process CPU time (user + system) of each run: with one thread
                it is robust to other work on the machine, which stretches wall times
  force_ratio = force_evaluations(explicit) / force_evaluations(orb)   (noise-free; orb counts
                each cross-leaf pair once per leaf side, see run.json)
  fine_leaf_fraction_mean = mean over output rows of the fraction of non-empty leaves on the
                fine step

Writes <out>/trade.csv, <out>/trade_observable.png (observable vs time per nsubit) and
<out>/trade_error_speedup.png (error and speed-up vs nsubit).

--noise-floor K (K >= 2) separates the scheme's error from chaos (tools/noise_floor.py): K - 1
more explicit runs start from the reference's initial state with every position moved by a
relative --perturbation (1e-12 of the domain's extent, one seed per run). For every observable
of --observables and each of --windows equal time windows, the floor is the largest error of
those runs against the reference, and each scheme's error in the same window is given next to
it with a verdict ("indistinguishable from chaos" or "scheme error E above the floor F").
Writes <out>/trade_floor.csv and draws the perturbed runs' envelope as a band in
trade_observable.png; trade.csv gains the whole-run floor of --observable.

The contact census (diagnostics columns of dem/contact_census.hpp; tools/census_errors.py): each
run's collision frequency, mean and largest overlap (and the wall ones, where the scene has walls)
and coordination-number distribution, reduced over each of the --windows windows and over the
whole run, against the reference's: relative errors, and the L1 distance of the coordination
distributions. With --noise-floor the same errors of the perturbed runs give their floor. The
collision frequencies also carry their sampling noise (the Poisson noise of the contacts the rows
caught, column sampling); the verdict weighs the error against the floor and twice that noise. Writes <out>/trade_census.csv (per quantity and window) and trade_census.png;
trade.csv gains the whole-run errors (collision_frequency_error, overlap_mean_error,
overlap_max_error, coordination_l1, and their *_floor with --noise-floor).

Example:
  tools/trade.py scenes/hcs.toml --levels 6 --end-time 0.01 --out runs/trade_hcs1222
  tools/trade.py scenes/hcs.toml --schemes islands --nsubit 10 20 --noise-floor 4 \
      --observables granular_temperature mean_speed --windows 3 --out runs/trade_hcs_floor
"""
import argparse
import csv
import json
import os
import resource
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import census_errors  # noqa: E402
import noise_floor  # noqa: E402

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def nsubit_arg(text):
    if text == "auto":
        return text
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"nsubit must be an integer >= 1 or auto, got {text!r}")
    return n


def mean_nsubit(ns, js):
    """The x position of a configuration: nsubit, or the mean count an auto run took."""
    if ns != "auto":
        return float(ns)
    return js["steps"] / max(1, round(js["end_time"] / js["control_interval"]))


def read_diag(path):
    with open(os.path.join(path, "diagnostics.csv")) as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


REUSE = False  # --reuse: take a configuration's finished run from its directory


def run(binary, scene, out, overrides, threads, repeat=1):
    """One configuration, `repeat` times in a row; loop_seconds is the minimum (the runs are
    deterministic, so only the wall time differs: the minimum is the least disturbed by load).
    cpu_seconds (user + system of the whole process, the minimum over the repeats) is added to
    the returned run.json: with one thread it is what the run cost even when other work shares
    the cores and stretches its wall time."""
    cmd = [binary, "run", scene, *overrides, "--threads", str(threads), "--quiet", "--overwrite", "--out", out]
    cpu_file = os.path.join(out, "trade_cpu_seconds")
    def without_census(js, cpu):
        """The loop's wall and CPU time without the contact census, which is the same work in
        every run: census_seconds off the wall time, its share of the loop off the CPU time."""
        census = js.get("census_seconds", 0.0)
        js["cpu_seconds"] = cpu * (1.0 - census / js["loop_seconds"])
        js["loop_seconds"] -= census
        return js

    if REUSE and all(os.path.exists(os.path.join(out, f))
                     for f in ("run.json", "diagnostics.csv", "trade_cpu_seconds")):
        with open(os.path.join(out, "run.json")) as f:
            js = json.load(f)
        with open(cpu_file) as f:
            return without_census(js, float(f.read())), read_diag(out)
    best, best_cpu = None, None
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        res = subprocess.run(cmd, capture_output=True, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if res.returncode != 0:
            sys.exit(f"trade.py: {' '.join(cmd)} failed:\n{res.stderr}")
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        with open(os.path.join(out, "run.json")) as f:
            js = without_census(json.load(f), cpu)
        if best_cpu is None or js["cpu_seconds"] < best_cpu[0]:
            best_cpu = (js["cpu_seconds"], cpu)
        if best is None or js["loop_seconds"] < best["loop_seconds"]:
            best = js
    best["cpu_seconds"] = best_cpu[0]
    with open(cpu_file, "w") as f:
        f.write(repr(best_cpu[1]))  # with the census: --reuse takes it off again
    return best, read_diag(out)


def census_key(q):
    """trade.csv's column of a census quantity's whole-run error."""
    return "coordination_l1" if q == "coordination" else f"{q}_error"


def census_value(d, q, w):
    """A run's census quantity reduced over window w; the coordination distribution as its mean
    coordination number (the last bin counted at its lower edge)."""
    v = census_errors.window_values(d, w)
    if v is None:
        return float("nan")
    if q == "coordination":
        return float(np.dot(np.arange(len(v[q])), v[q]))
    return v[q]


def plot_census(path, title, ref, perturbed_runs, runs, wins):
    """Left: the collision frequency per window (the perturbed runs' range as a band); right: the
    coordination distribution over the whole run."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    edges = np.array([wins[0][0]] + [w[1] for w in wins]) * 1e3

    def per_window(d):
        return [census_value(d, "collision_frequency", w) for w in wins]

    def step(ax, d, **kw):
        v = per_window(d)
        ax.stairs(v, edges, **kw)
    if perturbed_runs:
        env = np.array([per_window(d) for d in perturbed_runs] + [per_window(ref)])
        ax1.stairs(env.max(axis=0), edges, baseline=env.min(axis=0), fill=True, color="0.8",
                   label=f"chaos floor ({len(perturbed_runs) + 1} explicit runs)")
    step(ax1, ref, color="k", lw=2, label="explicit")
    whole = (0.0, ref["time"][-1])
    k = np.arange(len(census_errors.coordination_columns(ref)))
    ax2.semilogy(k, census_errors.window_values(ref, whole)["coordination"], "k-o", lw=2,
                 label="explicit")
    for label, d in runs:
        step(ax1, d, ls="--", label=label)
        ax2.semilogy(k, census_errors.window_values(d, whole)["coordination"], "--.", label=label)
    ax1.set_xlabel("t [ms]")
    ax1.set_ylabel("collision frequency per particle [1/s] (window mean)")
    ax1.legend(fontsize=7)
    ax2.set_xlabel("coordination number (last bin: 12 or more)")
    ax2.set_ylabel("fraction of particle-rows")
    ax2.legend(fontsize=7)
    fig.suptitle(f"{title}: contact census")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--nsubit", type=nsubit_arg, nargs="+", default=[5, 10, 15, 20, 30, 40],
                    help="sub-iterations per regrid interval; islands also take auto "
                         "(dem.nsubit = \"auto\", plotted at its mean count)")
    ap.add_argument("--levels", type=int, nargs="+", default=[4])
    ap.add_argument("--schemes", nargs="+", default=["orb"], choices=["orb", "islands"],
                    help="adaptive schemes to sweep (islands ignores --levels)")
    ap.add_argument("--observable", default="granular_temperature",
                    help="diagnostics.csv column: granular_temperature | mean_speed | mean_vy ...")
    ap.add_argument("--end-time", type=float, default=None, help="run.end_time override [s]")
    ap.add_argument("--set", action="append", default=[], help="extra key=value override (repeat)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs per configuration; wall time = the minimum (default 1)")
    ap.add_argument("--binary", default=os.path.join(os.path.dirname(__file__), "..", "build", "bin", "cfddem"))
    ap.add_argument("--out", default="runs/trade")
    ap.add_argument("--label", default=None, help="title of the plots (default: the scene)")
    ap.add_argument("--noise-floor", type=int, default=0, metavar="K",
                    help="K explicit references (the reference + K-1 perturbed runs): report the "
                         "chaos floor and a verdict per scheme (default 0: off)")
    ap.add_argument("--perturbation", type=float, default=1e-12,
                    help="relative position perturbation of the floor's runs (default 1e-12)")
    ap.add_argument("--observables", nargs="+", default=None,
                    help="observables of the floor table (default: --observable)")
    ap.add_argument("--windows", type=int, default=4, help="time windows of the floor table")
    ap.add_argument("--reuse", action="store_true",
                    help="take each configuration's run from its directory under --out when a "
                         "finished one is there (re-analysis of a sweep; the run.json of the last "
                         "repeat, the CPU time its sweep recorded)")
    a = ap.parse_args()
    global REUSE
    REUSE = a.reuse

    os.makedirs(a.out, exist_ok=True)
    # The census is off by default in cfddem (it costs a few explicit steps per row); the trade
    # compares it, so every run takes it (a --set output.contact_census=false after it wins).
    common = (["output.contact_census=true"] + list(a.set) +
              ([f"run.end_time={a.end_time}"] if a.end_time else []))
    ref_json, ref = run(a.binary, a.scene, os.path.join(a.out, "explicit"),
                        ["dem.scheme=\"explicit\""] + common, a.threads, a.repeat)
    if a.observable not in ref:
        sys.exit(f"trade.py: no column '{a.observable}' in diagnostics.csv (have: {', '.join(ref)})")
    t_ref, o_ref = ref["time"], ref[a.observable]
    observables = a.observables or [a.observable]
    for ob in observables:
        if ob not in ref:
            sys.exit(f"trade.py: no column '{ob}' in diagnostics.csv (have: {', '.join(ref)})")
    wins = noise_floor.windows(t_ref[-1], a.windows)
    # The contact census: its quantities, compared per window and over the whole run (last).
    census = census_errors.quantities(ref) if census_errors.has_census(ref) else []
    census_wins = wins + [(0.0, t_ref[-1])]
    census_floor, census_rows = {}, []
    whole = census_wins[-1]
    floor_rows, floor, floor_whole, perturbed_runs = [], {}, 0.0, []
    if a.noise_floor == 1 or a.noise_floor < 0:
        sys.exit("trade.py: --noise-floor needs K >= 2 (the reference and K-1 perturbed runs)")
    if a.noise_floor >= 2:
        plain = [o for o in common if not noise_floor.generator_override(o)]
        state = noise_floor.initial_state(a.binary, a.scene, common, a.out)
        lo, hi, per = noise_floor.domain_of(a.scene, common)
        for j in range(1, a.noise_floor):
            tag = f"floor_{j}"
            csv_path = os.path.join(a.out, f"{tag}.csv")
            noise_floor.write_particle_csv(
                noise_floor.perturbed(state, lo, hi, per, a.perturbation, seed=1000 + j), csv_path)
            scene_path = os.path.join(a.out, f"{tag}.toml")
            noise_floor.write_scene_with_file(a.scene, csv_path, scene_path)
            _, d = run(a.binary, scene_path, os.path.join(a.out, tag),
                       ["dem.scheme=\"explicit\""] + plain, a.threads, 1)
            perturbed_runs.append(d)
            floor_whole = max(floor_whole, noise_floor.window_error(
                d["time"], d[a.observable], t_ref, o_ref, (0.0, t_ref[-1])))
        for ob in observables:
            for w in wins:
                errs = [noise_floor.window_error(d["time"], d[ob], t_ref, ref[ob], w)
                        for d in perturbed_runs]
                floor[(ob, w)] = max(errs)
                floor_rows.append(dict(scheme="floor", nsubit=0, levels=0, observable=ob,
                                       window_start=w[0], window_end=w[1], error=max(errs),
                                       floor=max(errs), verdict=f"spread of {len(errs)} runs"))
        if census:
            for w in census_wins:
                errs = [census_errors.errors(d, ref, w, census) for d in perturbed_runs]
                for q in census:
                    census_floor[(q, w)] = max(e[q] for e in errs)
                    census_rows.append(dict(scheme="floor", nsubit=0, levels=0, quantity=q,
                                            window_start=w[0], window_end=w[1], value=float("nan"),
                                            ref_value=census_value(ref, q, w),
                                            error=census_floor[(q, w)],
                                            floor=census_floor[(q, w)],
                                            sampling=max(census_errors.sampling(x, ref, w, q)
                                                         for x in perturbed_runs),
                                            verdict=f"spread of {len(errs)} runs"))
        print(f"chaos floor ({a.noise_floor - 1} perturbed explicit runs, relative "
              f"{a.perturbation:g}): {100 * floor_whole:.3g}% in {a.observable} over the run",
              flush=True)
    rows = [dict(scheme="explicit", nsubit=0, nsubit_mean=0.0, levels=0, error=0.0, speedup=1.0, force_ratio=1.0,
                 fine_leaf_fraction_mean=1.0, loop_seconds=ref_json["loop_seconds"],
                 force_evaluations=ref_json["force_evaluations"], cpu_speedup=1.0,
                 cpu_seconds=ref_json["cpu_seconds"])]
    if a.noise_floor >= 2:
        rows[0]["floor"] = floor_whole
    for q in census:
        key = census_key(q)
        rows[0][key] = 0.0
        if a.noise_floor >= 2:
            rows[0][key + "_floor"] = census_floor[(q, whole)]
    curves, census_runs = {}, []
    # Series: (label, scheme, levels); the islands scheme has no ORB.
    series = []
    for sch in a.schemes:
        if sch == "orb":
            series += [(f"orb, {2 ** L} leaves", "orb", L) for L in a.levels]
        else:
            series.append(("islands", "islands", 0))
    for label, sch, L in series:
        for ns in a.nsubit:
            if ns == "auto" and sch == "orb":
                continue  # orb takes an integer
            name = f"orb_L{L}_n{ns}" if sch == "orb" else f"islands_n{ns}"
            extra = [f"partition.orb_levels={L}"] if sch == "orb" else []
            js, d = run(a.binary, a.scene, os.path.join(a.out, name),
                        [f"dem.scheme=\"{sch}\"", f"dem.nsubit={ns}"] + extra + common,
                        a.threads, a.repeat)
            t, o = d["time"], d[a.observable]
            keep = t <= t_ref[-1] + 1e-12
            o_at = np.interp(t[keep], t_ref, o_ref)
            err = np.mean(np.abs(o[keep] - o_at)) / abs(np.mean(o_at))
            fine = d["fine_leaf_fraction"][1:]
            rows.append(dict(scheme=sch, nsubit=ns, nsubit_mean=mean_nsubit(ns, js), levels=L,
                             error=err,
                             speedup=ref_json["loop_seconds"] / js["loop_seconds"],
                             force_ratio=ref_json["force_evaluations"] / max(js["force_evaluations"], 1),
                             fine_leaf_fraction_mean=float(np.mean(fine)) if len(fine) else float("nan"),
                             loop_seconds=js["loop_seconds"], force_evaluations=js["force_evaluations"],
                             cpu_speedup=ref_json["cpu_seconds"] / max(js["cpu_seconds"], 1e-9),
                             cpu_seconds=js["cpu_seconds"]))
            curves[(label, ns)] = (t, o)
            if a.noise_floor >= 2:
                rows[-1]["floor"] = floor_whole
                for ob in observables:
                    for w in wins:
                        e = noise_floor.window_error(t, d[ob], t_ref, ref[ob], w)
                        floor_rows.append(dict(scheme=sch, nsubit=ns, levels=L, observable=ob,
                                               window_start=w[0], window_end=w[1], error=e,
                                               floor=floor[(ob, w)],
                                               verdict=noise_floor.verdict(e, floor[(ob, w)])))
                        print(f"    {ob} in ({1e3 * w[0]:.3g}, {1e3 * w[1]:.3g}] ms: "
                              f"{floor_rows[-1]['verdict']}" +
                              (f" (error {100 * e:.3g}%, floor {100 * floor[(ob, w)]:.3g}%)"
                               if e <= floor[(ob, w)] else ""), flush=True)
            census_runs.append((f"{label} nsubit {ns}", d))
            for w in census_wins:
                errs = census_errors.errors(d, ref, w, census)
                for q in census:
                    fl = census_floor.get((q, w), 0.0)
                    noise = census_errors.sampling(d, ref, w, q)
                    census_rows.append(dict(
                        scheme=sch, nsubit=ns, levels=L, quantity=q, window_start=w[0],
                        window_end=w[1], value=census_value(d, q, w),
                        ref_value=census_value(ref, q, w), error=errs[q],
                        floor=fl if a.noise_floor >= 2 else float("nan"), sampling=noise,
                        verdict=census_errors.verdict(errs[q], fl, noise)))
                    if w == whole:
                        rows[-1][census_key(q)] = errs[q]
                        if a.noise_floor >= 2:
                            rows[-1][census_key(q) + "_floor"] = fl
            if census:
                print("    census over the run: " + ", ".join(
                    f"{q} {100 * rows[-1][census_key(q)]:.3g}%" +
                    (f" (floor {100 * census_floor[(q, whole)]:.3g}%)" if a.noise_floor >= 2 else "")
                    for q in census), flush=True)
            r = rows[-1]
            what = "fine leaves" if sch == "orb" else "fine particles"
            print(f"{label:>16} nsubit={ns!s:>4}: error {100 * err:6.2f}%  speed-up {r['speedup']:.2f}  "
                  f"cpu speed-up {r['cpu_speedup']:.2f}  force ratio {r['force_ratio']:.2f}  {what} {r['fine_leaf_fraction_mean']:.3f}",
                  flush=True)

    with open(os.path.join(a.out, "trade.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    if floor_rows:
        with open(os.path.join(a.out, "trade_floor.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(floor_rows[0]))
            w.writeheader()
            w.writerows(floor_rows)

    if census_rows:
        with open(os.path.join(a.out, "trade_census.csv"), "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(census_rows[0]))
            w.writeheader()
            w.writerows(census_rows)

    title = a.label or os.path.basename(a.scene)
    if census:
        plot_census(os.path.join(a.out, "trade_census.png"), title, ref, perturbed_runs,
                    census_runs, wins)
    fig, axes = plt.subplots(1, len(series), figsize=(6 * len(series), 4.5), squeeze=False)
    for ax, (label, sch, L) in zip(axes[0], series):
        ax.plot(t_ref * 1e3, o_ref, "k-", lw=2, label="explicit")
        if perturbed_runs:
            n = min(len(d["time"]) for d in perturbed_runs)
            tt = perturbed_runs[0]["time"][:n]
            env = np.array([np.interp(tt, d["time"], d[a.observable]) for d in perturbed_runs]
                           + [np.interp(tt, t_ref, o_ref)])
            ax.fill_between(tt * 1e3, env.min(axis=0), env.max(axis=0), color="0.75",
                            label=f"chaos floor ({len(perturbed_runs) + 1} explicit runs)")
        for ns in a.nsubit:
            if (label, ns) not in curves:
                continue
            t, o = curves[(label, ns)]
            ax.plot(t * 1e3, o, "--", label=f"nsubit {ns}")
        ax.set_xlabel("t [ms]")
        ax.set_ylabel(a.observable)
        ax.set_title(f"{title}: {label}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "trade_observable.png"), dpi=120)

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for label, sch, L in series:
        sel = sorted((r for r in rows if r["scheme"] == sch and r["levels"] == L),
                     key=lambda r: r["nsubit_mean"])
        ns = [r["nsubit_mean"] for r in sel]
        ax1.plot(ns, [100 * r["error"] for r in sel], "o-", label=label)
        ax2.plot(ns, [r["speedup"] for r in sel], "o-", label=f"wall, {label}")
        ax2.plot(ns, [r["force_ratio"] for r in sel], "s--", label=f"force evaluations, {label}")
    ax1.set_xlabel("nsubit (auto: its mean)")
    ax1.set_ylabel(f"error in {a.observable} [%]")
    ax1.legend()
    ax2.axhline(1.0, color="k", lw=0.8)
    ax2.set_xlabel("nsubit")
    ax2.set_ylabel("speed-up over explicit")
    ax2.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(os.path.join(a.out, "trade_error_speedup.png"), dpi=120)


if __name__ == "__main__":
    main()
