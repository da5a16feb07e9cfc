#!/usr/bin/env python3
"""The gas step's parts (run.json `fluid_phase_seconds`) of coupled scenes, side by side.

Runs each scene with each binary and thread count, alternating within a round (the machines are
shared: ratios are only worth quoting from runs taken side by side), and prints per run the gas
per fluid step, per cell, its share of the loop, the PCG iterations per step and every part, then
per part the ratio of the first thread count's seconds to each other's; with more than one scene,
each scene's gas per cell over the first scene's of the same round, binary and thread count.

    /usr/bin/python3 tools/gas_phases.py --bin build/bin/cfddem --threads 1 2 --rounds 2 \
        scenes/riser.toml scenes/fluidized_bed.toml -- run.end_time=0.002

Everything after `--` is passed to every run as scene overrides. Needs only the standard library.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile


def run(binary, scene, threads, overrides, out):
    cmd = [binary, "run", scene, "--out", out, "--threads", str(threads), "--quiet", "--overwrite",
           *overrides]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "run.json")) as f:
        return json.load(f)


def cells(report):
    n = report["configuration"]["fluid.cells"]
    return n[0] * n[1] * n[2]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--bin", action="append", required=True, help="cfddem binary (repeatable)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--work", default=None, help="directory for the runs (default: a temporary one)")
    argv = sys.argv[1:]
    split = argv.index("--") if "--" in argv else len(argv)
    args = ap.parse_args(argv[:split])
    overrides = argv[split + 1:]
    work = args.work or tempfile.mkdtemp(prefix="gas_phases.")
    rows = []
    for r in range(1, args.rounds + 1):
        for scene in args.scenes:
            for b, binary in enumerate(args.bin):
                for t in args.threads:
                    name = os.path.splitext(os.path.basename(scene))[0]
                    out = os.path.join(work, f"r{r}_b{b}_{name}_t{t}")
                    rep = run(binary, scene, t, overrides, out)
                    parts = rep["fluid_phase_seconds"]
                    steps = rep["fluid_steps"]
                    gas = sum(parts.values())
                    rows.append((r, b, name, t, rep, parts, gas, steps))
                    print(f"round {r} bin {b} {name} threads {t}: gas {1e3 * gas / steps:.2f} ms"
                          f"/step, {1e9 * gas / steps / cells(rep):.3f} ns/cell, share"
                          f" {100 * gas / rep['loop_seconds']:.1f}% of the loop"
                          f" ({rep['loop_seconds']:.3f} s), PCG"
                          f" {rep.get('projection_iterations', 0) / steps:.1f}/step; "
                          + ", ".join(f"{k} {v:.4f}" for k, v in parts.items()), flush=True)
    if len(args.scenes) > 1:
        # Issue 36's measure: each scene's gas per cell over the first scene's, both of one round,
        # binary and thread count (runs minutes apart on a shared machine are not comparable).
        first = os.path.splitext(os.path.basename(args.scenes[0]))[0]
        print(f"\ngas per cell / {first}'s of the same round, binary and threads:")
        for r, b, name, t, rep, parts, gas, steps in rows:
            if name == first:
                continue
            ref = next(x for x in rows if x[0] == r and x[1] == b and x[2] == first and x[3] == t)
            per_cell = gas / steps / cells(rep)
            ref_cell = ref[6] / ref[7] / cells(ref[4])
            print(f"round {r} bin {b} {name} threads {t}: {per_cell / ref_cell:.3f}x "
                  f"({1e9 * per_cell:.1f} / {1e9 * ref_cell:.1f} ns)")
    if len(args.threads) > 1:
        base = args.threads[0]
        print(f"\nper part, seconds at {base} thread(s) / at each other count = ratio:")
        for r, b, name, t, rep, parts, gas, steps in rows:
            if t == base:
                continue
            ref = next(x for x in rows if x[:3] == (r, b, name) and x[3] == base)
            ratios = {k: (ref[5][k], parts[k]) for k in parts}
            print(f"round {r} bin {b} {name} {base}->{t}: gas {ref[6] / gas:.2f}, loop"
                  f" {ref[4]['loop_seconds'] / rep['loop_seconds']:.2f}; "
                  + ", ".join(f"{k} {a:.3f}/{c:.3f}={a / c if c > 0 else float('nan'):.2f}"
                              for k, (a, c) in ratios.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
