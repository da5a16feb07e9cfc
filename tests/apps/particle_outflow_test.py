#!/usr/bin/env python3
"""Particles leaving through an outflow face (scenes/elutriation.toml, apps/particle_outflow.hpp).

For every scheme on one rank:
- the mass balance of every diagnostics row closes: particle_mass + mass_out equals the mass at
  t = 0 within 1e-12 relative (a sum of a few hundred masses of equal size: round-off is 1e-14);
- the count only falls, is the held mass over one particle's mass, and most of the bed has left
  by 10 ms (the inflow is four times the terminal velocity);
- with particles.outflow = "wall" no particle leaves (the old behaviour, now a stated choice);
- a restart from a checkpoint taken while particles leave repeats the run bit for bit.
On 2 ranks (where mpirun is found) the run stops with exit code 3 and a message naming the face.

Usage: particle_outflow_test.py CFDDEM SOURCE_DIR [MPIEXEC]
"""
import csv
import os
import shutil
import subprocess
import sys
import tempfile

CFDDEM, SOURCE = sys.argv[1], sys.argv[2]
MPIEXEC = sys.argv[3] if len(sys.argv) > 3 else shutil.which("mpirun")
SCENE = os.path.join(SOURCE, "scenes", "elutriation.toml")


def run(out, *extra, check=True):
    p = subprocess.run([CFDDEM, "run", SCENE, *extra, "--quiet", "--overwrite", "--out", out],
                       capture_output=True, text=True, timeout=240)
    if check and p.returncode != 0:
        raise AssertionError(f"cfddem failed ({p.returncode}): {p.stderr}")
    return p


def rows(out):
    with open(os.path.join(out, "diagnostics.csv")) as f:
        return list(csv.DictReader(f))


def check_balance(scheme, tmp):
    out = os.path.join(tmp, scheme)
    run(out, f"dem.scheme={scheme}")
    r = rows(out)
    m0 = float(r[0]["particle_mass"])
    n0 = int(float(r[0]["particles"]))
    mp = m0 / n0
    last = n0
    for x in r:
        held, gone = float(x["particle_mass"]), float(x["mass_out"])
        n = int(float(x["particles"]))
        assert abs(held + gone - m0) <= 1e-12 * m0, (scheme, x["time"], held, gone, m0)
        assert float(x["mass_in"]) == 0.0, x["mass_in"]
        assert n <= last, (scheme, x["time"], n, last)
        assert abs(held - n * mp) <= 1e-12 * m0, (scheme, x["time"], held, n)
        last = n
    assert last < n0 // 2, (scheme, "most of the bed should have left by 10 ms", last)
    print(f"{scheme}: {n0} -> {last} particles, balance closes at every row")


def check_restart(scheme, tmp):
    full, second = os.path.join(tmp, f"full_{scheme}"), os.path.join(tmp, f"second_{scheme}")
    common = [f"dem.scheme={scheme}", "run.end_time=0.007"]
    run(full, *common, "output.checkpoint_interval=0.005")
    r = rows(full)
    at5 = [x for x in r if abs(float(x["time"]) - 0.005) < 1e-9][0]
    assert float(at5["mass_out"]) > 0 and int(float(r[-1]["particles"])) < int(float(at5["particles"]))
    run(second, *common, "--restart", os.path.join(full, "checkpoint_000000050.h5"))
    a, b = rows(full), rows(second)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for k in x:
            if k != "wall_seconds":
                assert x[k] == y[k], (scheme, x["time"], k, x[k], y[k])
    print(f"{scheme}: restart across removals is bitwise")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        for scheme in ("explicit", "orb", "islands"):
            check_balance(scheme, tmp)
            check_restart(scheme, tmp)
        wall = os.path.join(tmp, "wall")
        run(wall, 'particles.outflow="wall"', "run.end_time=0.006")
        assert all(int(float(x["particles"])) == 400 and float(x["mass_out"]) == 0.0
                   for x in rows(wall))
        if MPIEXEC:
            env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
            out = os.path.join(tmp, "ranks")
            p = subprocess.run([MPIEXEC, "-np", "2", "--oversubscribe", CFDDEM, "run", SCENE,
                                "--quiet", "--out", out], capture_output=True, text=True,
                               env=env, timeout=240)
            assert p.returncode == 3, (p.returncode, p.stderr)
            assert "reached an outflow face" in p.stderr and "particles.outflow" in p.stderr, p.stderr
            print("2 ranks: stops with", p.stderr.strip().splitlines()[-1])
    print("OK")


if __name__ == "__main__":
    main()
