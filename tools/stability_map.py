#!/usr/bin/python3
"""Stability map of the DEM time integration (issue 6): for each scheme, sweep the time step
(tau_p/dt), the restitution e, the spring constant k over decades and the impact speed, run a
head-on binary collision with `cfddem run`, and classify each run:

  accurate    the kinetic energy after impact is e^2 of the energy before, to --bound (default
              1% of the initial energy): KE_after/KE_before within e^2 +- bound
  inaccurate  it ran to the end, but the energy ratio misses e^2 by more than the bound
  unstable    the run stopped itself (exit code 3: unstable step, overlap beyond dem.max_overlap,
              tunnelling, NaN) or produced NaN

With orb, the two particles start in different leaves (1 ORB level, dt_f = 1e-4 s, nsubit 10):
a leaf with a partner within 3 radii steps at tau_p/dt, else at dt_sp = 1e-5 s.

Theory (docs/theory.md §2): velocity Verlet on a linear spring is stable for omega dt < 2, i.e.
tau_p/dt > sqrt(2)/2 for two equal spheres (omega = sqrt(2k/m)); accuracy needs far more.
Writes DIR/stability.csv and DIR/stability.png (one panel per k and impact speed per scheme).

usage: /usr/bin/python3 tools/stability_map.py [--cfddem build/bin/cfddem] [--out DIR]
       [--schemes explicit,orb] [--tau-per-dt 0.5,1,2,5,10,20,50,100,200] [--e 0,0.2,0.5,0.8,1]
       [--k 1,10,100,1000] [--speed 0.1,1,5] [--bound 0.01]
"""
import argparse
import csv
import math
import os
import subprocess
import sys

import numpy as np

D, RHO = 100e-6, 1000.0
MASS = RHO * math.pi * D**3 / 6.0


def run_case(exe, out, scheme, tau_per_dt, e, k, speed):
    """One head-on collision at closing speed 2*speed; returns (class, energy_ratio, code)."""
    os.makedirs(out, exist_ok=True)
    csv_path = os.path.join(out, "pair.csv")
    gap = 20e-6
    with open(csv_path, "w") as f:
        f.write("x,y,z,vx,vy,vz,diameter,density\n")
        f.write(f"{0.5e-3 - 0.5 * (D + gap)},5e-4,5e-4,{speed},0,0,{D},{RHO}\n")
        f.write(f"{0.5e-3 + 0.5 * (D + gap)},5e-4,5e-4,{-speed},0,0,{D},{RHO}\n")
    # Long enough to close the gap and finish a contact of a few pi/omega.
    t_contact = math.pi * math.sqrt(MASS / 2 / k)
    end = gap / (2 * speed) + 3 * t_contact
    args = [exe, "run", csv_scene(out), "--quiet", "--overwrite", "--out", os.path.join(out, "run"),
            f"particles.file={csv_path}", f"dem.spring_constant={k}", f"dem.restitution={e}",
            f"dem.dt_factor={1.0 / tau_per_dt}", f"dem.scheme={scheme}",
            f"run.end_time={end}", f"output.interval={end / 4}"]
    if scheme == "orb":
        # The paper's settings: dt_f = 1e-4 s, 10 sub-iterations; the two particles start in
        # different leaves, so their contact is computed against frozen ghosts.
        args += ["partition.orb_levels=1", "dem.nsubit=10", "dem.regrid_interval=1e-4"]
    r = subprocess.run(args, capture_output=True, text=True)
    if r.returncode == 3:
        return "unstable", float("nan"), 3
    if r.returncode != 0:
        raise RuntimeError(f"cfddem failed ({r.returncode}): {r.stderr.strip()}")
    rows = list(csv.DictReader(open(os.path.join(out, "run", "diagnostics.csv"))))
    ke0, ke1 = float(rows[0]["kinetic_energy"]), float(rows[-1]["kinetic_energy"])
    ratio = ke1 / ke0
    if not math.isfinite(ratio):
        return "unstable", ratio, 0
    return ("accurate" if abs(ratio - e * e) <= ARGS.bound else "inaccurate"), ratio, 0


def csv_scene(out):
    path = os.path.join(out, "pair.toml")
    with open(path, "w") as f:
        f.write("[domain]\nlo = [0.0, 0.0, 0.0]\nhi = [1.0e-3, 1.0e-3, 1.0e-3]\n"
                "[particles]\nfile = \"pair.csv\"\n[dem]\nspring_constant = 10.0\n"
                "restitution = 0.8\n[run]\nend_time = 1.0e-4\n")
    return path


def plot(rows, schemes, ks, speeds, taus, es, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    code = {"accurate": 0, "inaccurate": 1, "unstable": 2}
    cmap = ListedColormap(["#2ca02c", "#ffbf00", "#d62728"])
    fig, axes = plt.subplots(len(schemes) * len(ks), len(speeds),
                             figsize=(3.2 * len(speeds), 2.6 * len(schemes) * len(ks)),
                             squeeze=False)
    for si, s in enumerate(schemes):
        for ki, k in enumerate(ks):
            for vi, v in enumerate(speeds):
                ax = axes[si * len(ks) + ki][vi]
                grid = np.full((len(es), len(taus)), np.nan)
                for r in rows:
                    if r["scheme"] == s and r["k"] == k and r["speed"] == v:
                        grid[es.index(r["e"]), taus.index(r["tau_per_dt"])] = code[r["class"]]
                ax.imshow(grid, origin="lower", cmap=cmap, vmin=0, vmax=2, aspect="auto")
                ax.set_xticks(range(len(taus)), [f"{t:g}" for t in taus], fontsize=7)
                ax.set_yticks(range(len(es)), [f"{x:g}" for x in es], fontsize=7)
                ax.set_title(f"{s}, k={k:g} N/m, v={v:g} m/s", fontsize=8)
                if vi == 0:
                    ax.set_ylabel("e", fontsize=8)
                ax.set_xlabel("tau_p/dt", fontsize=8)
    fig.suptitle("green: accurate, amber: inaccurate, red: stopped by the run's checks", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def floats(s):
    return [float(x) for x in s.split(",")]


def main():
    global ARGS
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cfddem", default="build/bin/cfddem")
    ap.add_argument("--out", default="runs/stability_map")
    ap.add_argument("--schemes", default="explicit,orb")
    ap.add_argument("--tau-per-dt", default="0.5,1,2,5,10,20,50,100,200")
    ap.add_argument("--e", default="0,0.2,0.5,0.8,1")
    ap.add_argument("--k", default="1,10,100,1000")
    ap.add_argument("--speed", default="0.1,1,5")
    ap.add_argument("--bound", type=float, default=0.01)
    ARGS = ap.parse_args()
    exe = os.path.abspath(ARGS.cfddem)
    if not os.path.exists(exe):
        sys.exit(f"no cfddem at {exe}: build first (cmake --build build)")
    schemes = ARGS.schemes.split(",")
    taus, es, ks, speeds = (floats(ARGS.tau_per_dt), floats(ARGS.e), floats(ARGS.k),
                            floats(ARGS.speed))
    rows = []
    work = os.path.join(ARGS.out, "work")
    for s in schemes:
        for k in ks:
            for v in speeds:
                for e in es:
                    for t in taus:
                        cls, ratio, rc = run_case(exe, work, s, t, e, k, v)
                        rows.append({"scheme": s, "k": k, "speed": v, "e": e, "tau_per_dt": t,
                                     "omega_dt": math.sqrt(2.0) / t, "class": cls,
                                     "energy_ratio": ratio, "exit_code": rc})
                print(f"{s:8s} k={k:<6g} v={v:<4g} " + " ".join(
                    r["class"][0] for r in rows[-len(es) * len(taus):]), flush=True)
    os.makedirs(ARGS.out, exist_ok=True)
    with open(os.path.join(ARGS.out, "stability.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    plot(rows, schemes, ks, speeds, taus, es, os.path.join(ARGS.out, "stability.png"))
    # The boundary: the smallest tau_p/dt at which every (e, k, speed) case is accurate.
    for s in schemes:
        ok = [t for t in taus if all(r["class"] == "accurate" for r in rows
                                     if r["scheme"] == s and r["tau_per_dt"] == t
                                     and r["speed"] < 5)]
        print(f"{s}: every case with impact speed < 5 m/s accurate from tau_p/dt = "
              f"{min(ok) if ok else 'none'}")
    print(f"wrote {ARGS.out}/stability.csv and stability.png")


if __name__ == "__main__":
    main()
