#!/usr/bin/env python3
"""tools/plot_islands.py on a real run: a short islands run of scenes/hcs_small.toml gives a
run.json with island sizes that add up (lone particles + members = particles x sub-iterations)
and per-particle fine fractions in [0, 1] in increasing percentiles; the tool writes a PNG; on an
explicit run it refuses with exit status 1 and a message naming the directory. And
tools/plot_nsubit.py on a dem.nsubit = "auto" run (refusing an integer-nsubit one).

Usage: islands_tools_test.py CFDDEM SOURCE_DIR
"""
import json
import os
import subprocess
import sys
import tempfile

CFDDEM, SOURCE = sys.argv[1], sys.argv[2]
SCENE = os.path.join(SOURCE, "scenes", "hcs_small.toml")
TOOL = os.path.join(SOURCE, "tools", "plot_islands.py")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        isl, exp = os.path.join(tmp, "islands"), os.path.join(tmp, "explicit")
        common = ["run.end_time=0.002", "--threads", "1", "--quiet"]
        subprocess.run([CFDDEM, "run", SCENE, "dem.scheme=islands", "dem.nsubit=10", "--out", isl]
                       + common, check=True, timeout=120)
        subprocess.run([CFDDEM, "run", SCENE, "--out", exp] + common, check=True, timeout=120)
        with open(os.path.join(isl, "run.json")) as f:
            js = json.load(f)
        assert js["scheme"] == "islands" and js["bound_violations"] == 0, js
        subits = js["steps"]
        sizes = js["island_sizes"]
        assert "1" in sizes and sum(sizes.values()) >= subits, sizes
        d = js["fine_fraction_per_particle"]
        keys = ["min", "p10", "p50", "p90", "p99", "max"]
        vals = [d[k] for k in keys]
        assert all(0.0 <= v <= 1.0 for v in vals) and vals == sorted(vals), d
        assert d["min"] <= d["mean"] <= d["max"], d
        out = os.path.join(tmp, "islands.png")
        subprocess.run(["/usr/bin/python3", TOOL, isl, "--out", out], check=True, timeout=120)
        with open(out, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n", "not a PNG"
        bad = subprocess.run(["/usr/bin/python3", TOOL, exp], capture_output=True, text=True)
        assert bad.returncode == 1 and exp in bad.stderr, (bad.returncode, bad.stderr)
    print("plot_islands: run.json fields consistent, PNG written, explicit run refused")
    nsubit_tool()


def nsubit_tool():
    """tools/plot_nsubit.py on a dem.nsubit = "auto" run: the choices tile the run's control
    intervals, each within its bounds; a PNG; an integer-nsubit run refused."""
    tool = os.path.join(SOURCE, "tools", "plot_nsubit.py")
    with tempfile.TemporaryDirectory() as tmp:
        auto, fixed = os.path.join(tmp, "auto"), os.path.join(tmp, "fixed")
        common = ["dem.scheme=islands", "run.end_time=0.002", "--threads", "1", "--quiet"]
        subprocess.run([CFDDEM, "run", SCENE, "dem.nsubit=auto", "--out", auto] + common,
                       check=True, timeout=120)
        subprocess.run([CFDDEM, "run", SCENE, "dem.nsubit=10", "--out", fixed] + common,
                       check=True, timeout=120)
        with open(os.path.join(auto, "run.json")) as f:
            js = json.load(f)
        rows = js["nsubit_choices"]
        assert sum(r["intervals"] for r in rows) == round(0.002 / js["control_interval"]), rows
        assert all(r["nsubit_min"] <= r["nsubit"] <= r["nsubit_max"] for r in rows), rows
        assert all(abs(r["dt_sp"] * r["nsubit"] - js["control_interval"]) < 1e-15 for r in rows)
        out = os.path.join(tmp, "nsubit.png")
        subprocess.run(["/usr/bin/python3", tool, auto, "--out", out, "--quiet"], check=True,
                       timeout=120)
        with open(out, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n", "not a PNG"
        bad = subprocess.run(["/usr/bin/python3", tool, fixed], capture_output=True, text=True)
        assert bad.returncode == 1 and fixed in bad.stderr, (bad.returncode, bad.stderr)
    print(f"plot_nsubit: {len(rows)} choices tile the run, PNG written, integer nsubit refused")


if __name__ == "__main__":
    main()
