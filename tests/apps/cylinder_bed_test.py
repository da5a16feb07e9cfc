#!/usr/bin/env python3
"""A round fluidized bed (scenes/cylinder_bed.toml at a quarter of its cross-section: 0.8 mm
diameter, 8 x 50 x 8 cells, 1,500 particles, 0.1 s) on 1 rank (explicit) and 2 ranks (islands):
the time-averaged pressure drop over [0.05, 0.1] s within 5% of the bed's buoyant weight over
the column's area pi R^2 plus the gas head (issue 40's bar; tools/fluidized_bed_check.py, which
reads the area from run.json). The gas sees the column as a staircase of solid cells
(docs/theory.md §13), so the drop also checks that no gas passes through the wall: gas leaking
round the bed would carry less of its weight.

Usage: cylinder_bed_test.py CFDDEM SOURCE_DIR [MPIEXEC]
"""
import os
import shutil
import subprocess
import sys
import tempfile

CFDDEM, SOURCE = sys.argv[1], sys.argv[2]
MPIEXEC = sys.argv[3] if len(sys.argv) > 3 else shutil.which("mpirun")
SCENE = os.path.join(SOURCE, "scenes", "cylinder_bed.toml")
CHECK = os.path.join(SOURCE, "tools", "fluidized_bed_check.py")
SMALL = ["domain.hi=[0.8e-3,1.0e-2,0.8e-3]", "domain.cylinder_radius=0.4e-3",
         "particles.count=1500", "particles.region_hi=[0.8e-3,5.4e-3,0.8e-3]",
         "fluid.cells=[8,50,8]", "run.end_time=0.1", "name=cylinder_bed_small"]


def run(out, scheme, ranks):
    cmd = [CFDDEM, "run", SCENE, *SMALL, f"dem.scheme={scheme}", "--threads", "1", "--quiet",
           "--overwrite", "--out", out]
    env = None
    if ranks > 1:
        cmd = [MPIEXEC, "-np", str(ranks), "--oversubscribe", *cmd]
        env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert p.returncode == 0, (scheme, ranks, p.returncode, p.stderr)
    c = subprocess.run([sys.executable, CHECK, "--run-dir", out, "--from", "0.05", "--tol", "0.05"],
                       capture_output=True, text=True, timeout=60)
    print(f"{scheme}, {ranks} rank(s):\n{c.stdout}", flush=True)
    assert c.returncode == 0, (scheme, ranks, c.stdout, c.stderr)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        run(os.path.join(tmp, "explicit_1"), "explicit", 1)
        if MPIEXEC:
            run(os.path.join(tmp, "islands_2"), "islands", 2)
    print("cylinder bed: pressure drop within 5% on every run")


if __name__ == "__main__":
    main()
