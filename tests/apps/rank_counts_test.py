#!/usr/bin/env python3
"""run.json's rank_counts on R ranks: counts, not times.

Usage: rank_counts_test.py MPIEXEC CFDDEM SOURCE_DIR

For explicit, orb and islands (DEM only) and a coupled settling run, the same R-rank run is made
with 1 and with 2 threads per rank: the per-rank counts (work and messages) must be identical,
since they depend on the configuration and the rank count only, not on timing or threads. The
owned particle steps of the ranks add up exactly to the run's particle_steps, and a coupled
run's cell updates to the gas cells times the gas sub-steps. The parallel ORB's search bytes are
counted (DEM-only runs regrid with it) and are part of the collective bytes. Arrays have one entry per rank.
"""
import json
import os
import subprocess
import sys
import tempfile

MPIEXEC, CFDDEM, SOURCE = sys.argv[1], sys.argv[2], sys.argv[3]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
CASES = [
    ("hcs_small.toml", ["dem.scheme=explicit", "run.end_time=0.002"]),
    ("hcs_small.toml", ["dem.scheme=orb", "dem.nsubit=10", "run.end_time=0.002"]),
    ("hcs_small.toml", ["dem.scheme=islands", "dem.nsubit=10", "run.end_time=0.002"]),
    ("settling.toml", ["run.end_time=0.002"]),
]
FIELDS = ["particle_steps", "force_evaluations", "cell_updates", "p2p_messages", "p2p_bytes",
          "collectives", "collective_bytes", "reductions", "orb_search_bytes"]


def run(ranks, threads, scene, extra, out):
    cmd = [MPIEXEC, "-np", str(ranks), "--oversubscribe", CFDDEM, "run",
           os.path.join(SOURCE, "scenes", scene), "--out", out, "--quiet", "--threads",
           str(threads)] + extra
    subprocess.run(cmd, check=True, env=ENV, timeout=120, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "run.json")) as f:
        return json.load(f)


def main():
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, (scene, extra) in enumerate(CASES):
            ranks = 3 if n == 0 else 2
            a = run(ranks, 1, scene, extra, os.path.join(tmp, f"c{n}_t1"))
            b = run(ranks, 2, scene, extra, os.path.join(tmp, f"c{n}_t2"))
            name = f"{scene} {' '.join(extra)} on {ranks} ranks"
            ca, cb = a.get("rank_counts"), b.get("rank_counts")
            if ca is None:
                failures.append(f"{name}: run.json has no rank_counts")
                continue
            for k in FIELDS:
                if len(ca[k]) != ranks:
                    failures.append(f"{name}: {k} has {len(ca[k])} entries, {ranks} ranks")
                if ca[k] != cb[k]:
                    failures.append(f"{name}: {k} differs between 1 and 2 threads: {ca[k]} vs {cb[k]}")
            if sum(ca["particle_steps"]) != a["particle_steps"]:
                failures.append(f"{name}: ranks' particle steps {sum(ca['particle_steps'])} != "
                                f"the run's {a['particle_steps']}")
            if min(ca["p2p_messages"]) <= 0 or min(ca["reductions"]) <= 0:
                failures.append(f"{name}: a rank sent nothing: {ca}")
            # The ORB's searches are part of the collective payload; the DEM-only schemes regrid
            # with the parallel ORB (the coupled explicit run owns by the gas boxes instead).
            if any(s > c for s, c in zip(ca["orb_search_bytes"], ca["collective_bytes"])):
                failures.append(f"{name}: orb_search_bytes above collective_bytes: {ca}")
            if scene != "settling.toml" and min(ca["orb_search_bytes"]) <= 0:
                failures.append(f"{name}: no parallel ORB search counted: {ca}")
            if "gas_substeps" in a:
                with open(os.path.join(SOURCE, "scenes", scene), "rb") as f:
                    import tomllib
                    cells = tomllib.load(f)["fluid"]["cells"]
                want = cells[0] * cells[1] * cells[2] * a["gas_substeps"]
                if sum(ca["cell_updates"]) != want:
                    failures.append(f"{name}: cell updates {sum(ca['cell_updates'])} != {want}")
            print(f"{name}: {'ok' if not failures else 'checked'}", flush=True)
    for f in failures:
        print("FAIL:", f)
    print(f"{len(CASES) - len({f.split(':')[0] for f in failures})} passed, "
          f"{len({f.split(':')[0] for f in failures})} failed")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
