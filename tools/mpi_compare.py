#!/usr/bin/env python3
"""Ranks x threads on one node: particle-steps/s and loop time of a scheme for each layout.

    /usr/bin/python3 tools/mpi_compare.py [--scene scenes/hcs.toml] [--end-time 0.005]
        [--layouts 1x2,2x1] [--reps 3] [--csv tools/mpi_results/hcs.csv] [key=value ...]
    /usr/bin/python3 tools/mpi_compare.py --weak-per-core 50000 --layouts 1x1,2x1,4x1,...

Each layout RxT runs `mpirun -np R --map-by ppr:R:node:pe=T --bind-to core cfddem run SCENE
--threads T` (1 rank: the serial ExplicitScheme; more: the distributed one; `dem.scheme=orb`
among the overrides: OrbScheme, or the distributed orb) and reads run.json:
particle_steps_per_second and loop_seconds of the stepping loop (compare schemes by the loop
time: an orb particle step is not an explicit one), the MPI wait of the slowest rank and the
load imbalance. The median of --reps runs is reported; the 1-minute load average before each run is
recorded, since a busy machine makes the numbers meaningless. Efficiency: particle-steps/s per
core over the first layout's per core (strong scaling: same scene; weak scaling with
--weak-per-core N: scenes/hcs_small.toml with N particles per core at solid fraction --phi,
the periodic box grown with the core count).
"""
import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes", "hcs.toml"))
    ap.add_argument("--end-time", type=float, default=0.005)
    ap.add_argument("--layouts", default="1x2,2x1")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--cfddem", default=os.path.join(ROOT, "build", "bin", "cfddem"))
    ap.add_argument("--csv", default=None)
    ap.add_argument("--weak-per-core", type=int, default=0)
    ap.add_argument("--phi", type=float, default=0.01)
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    rows = []
    for layout in a.layouts.split(","):
        ranks, threads = (int(v) for v in layout.split("x"))
        scene, overrides = a.scene, list(a.overrides)
        if a.weak_per_core > 0:
            n = a.weak_per_core * ranks * threads
            d = 100e-6  # scenes/hcs_small.toml
            side = (n * 3.141592653589793 / 6 * d**3 / a.phi) ** (1 / 3)
            scene = os.path.join(ROOT, "scenes", "hcs_small.toml")
            overrides += [f"particles.count={n}", f"domain.hi=[{side},{side},{side}]"]
        rates, waits, imb, loads, loops = [], [], [], [], []
        for _ in range(a.reps):
            loads.append(os.getloadavg()[0])
            with tempfile.TemporaryDirectory() as out:
                cmd = ["mpirun", "-np", str(ranks), "--map-by", f"ppr:{ranks}:node:pe={threads}",
                       "--bind-to", "core", a.cfddem, "run", scene,
                       f"run.end_time={a.end_time}", "output.interval=1e-3", *overrides,
                       "--threads", str(threads), "--quiet", "--overwrite", "--out", out]
                subprocess.run(cmd, check=True, env=env)
                with open(os.path.join(out, "run.json")) as f:
                    j = json.load(f)
            rates.append(j["particle_steps_per_second"])
            loops.append(j["loop_seconds"])
            waits.append(max(j.get("mpi_wait_seconds", [0.0])) / j["loop_seconds"])
            imb.append(j.get("load_imbalance_max", 1.0))
        row = {"ranks": ranks, "threads": threads, "cores": ranks * threads,
               "particles": j["particles"], "steps": j["steps"],
               "particle_steps_per_second": statistics.median(rates),
               "min": min(rates), "max": max(rates), "loop_seconds": statistics.median(loops),
               "scheme": j.get("scheme", "explicit"),
               "mpi_wait_fraction": statistics.median(waits), "load_imbalance_max": max(imb),
               "load_average_max": max(loads)}
        base = rows[0] if rows else row
        row["efficiency"] = (row["particle_steps_per_second"] / row["cores"]) / (
            base["particle_steps_per_second"] / base["cores"])
        rows.append(row)
        print(f"{ranks} rank(s) x {threads} thread(s), {row['scheme']}: loop {row['loop_seconds']:.3f} s, "
              f"{row['particle_steps_per_second']:.4g} "
              f"particle-steps/s (min {row['min']:.4g}, max {row['max']:.4g}), MPI wait "
              f"{100 * row['mpi_wait_fraction']:.1f}% of the loop, imbalance "
              f"{row['load_imbalance_max']:.3f}, efficiency {row['efficiency']:.2f}, "
              f"{row['particles']} particles, load average <= {row['load_average_max']:.2f}",
              flush=True)
    if a.csv:
        os.makedirs(os.path.dirname(os.path.abspath(a.csv)), exist_ok=True)
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
