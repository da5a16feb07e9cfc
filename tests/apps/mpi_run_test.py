#!/usr/bin/env python3
"""`mpirun -np R cfddem run` against the 1-rank run: diagnostics.csv agrees to round-off.

Usage: mpi_run_test.py MPIEXEC CFDDEM SOURCE_DIR RANKS

The 1-rank run is the serial ExplicitScheme; the R-rank run the distributed one, whose forces
sum in another order. Over this run (a dilute HCS, a few hundred collisions) round-off grows
by far less than 1e6, so every column agrees to 1e-9 of its scale: the column's largest value,
or, for quantities that are zero up to round-off (momentum, mean velocity and acceleration),
the thermal scale sqrt(2 M KE0), sqrt(2 KE0 / M) and that over the output interval. Counters
(steps, particles, particle steps, force evaluations, neighbor builds) agree exactly. run.json
of the R-rank run names the ranks, threads, MPI wait per rank and the load imbalance. The
snapshots (written collectively with R ranks) hold the same particles (compared by id) at the
same positions and velocities to 1e-9 of a diameter and of the thermal speed (h5py, when
installed). Then a checkpoint/restart on R ranks continues bit for bit (restart_is_exact).
All of it again with friction (tangential springs with history, spin) in a denser gas (20%
solids), whose checkpoint must carry contacts with a loaded spring.
"""
import csv
import json
import math
import os
import subprocess
import sys
import tempfile

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
SCENE = os.path.join(SOURCE, "scenes", "hcs_small.toml")
ARGS = ["run.end_time=0.004", "output.interval=2e-4", "output.snapshot_interval=2e-3",
        "--threads", "1", "--quiet"]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
EXACT = ["time", "step", "particles", "particle_steps", "force_evaluations", "neighbor_builds"]
SKIP = ["wall_seconds"]
# Denser, so chaos amplifies round-off faster: half the run time keeps it within the bound.
FRICTION = ["dem.friction=0.5", "domain.hi=[0.64e-3,0.64e-3,0.64e-3]", "run.end_time=0.002",
            "output.snapshot_interval=1e-3"]


def snapshots(out):
    try:
        import h5py
    except ImportError:
        return None
    found = {}
    for name in sorted(os.listdir(out)):
        if name.startswith("snapshot_") and name.endswith(".h5"):
            with h5py.File(os.path.join(out, name), "r") as f:
                p = f["particles"]
                order = p["id"][()].argsort()  # the serial store is in cell order
                found[name] = {k: p[k][()][order] for k in ("id", "position", "velocity")}
    return found


def run(ranks, out, extra):
    cmd = [MPIEXEC, "-np", str(ranks), "--oversubscribe", CFDDEM, "run", SCENE, "--out", out] + ARGS + extra
    subprocess.run(cmd, check=True, env=ENV, timeout=120)
    with open(os.path.join(out, "diagnostics.csv")) as f:
        rows = list(csv.DictReader(f))
    with open(os.path.join(out, "run.json")) as f:
        info = json.load(f)
    return rows, info, snapshots(out)


def main():
    compare([])
    restart_is_exact([], 2e-3)
    compare(FRICTION)
    restart_is_exact(FRICTION, 1e-3)


def compare(extra):
    with tempfile.TemporaryDirectory() as tmp:
        one, _, snap_one = run(1, os.path.join(tmp, "np1"), extra)
        many, info, snap_many = run(RANKS, os.path.join(tmp, f"np{RANKS}"), extra)
    assert len(one) == len(many) > 10, (len(one), len(many))
    ke0 = float(one[0]["kinetic_energy"])
    mass = 100 * 1000.0 * math.pi / 6 * (100e-6) ** 3  # hcs_small: 100 particles, d, rho
    v_scale = math.sqrt(2 * ke0 / mass)
    scale = {c: max(abs(float(r[c])) for r in one) for c in one[0]}
    for a in "xyz":
        scale[f"momentum_{a}"] = math.sqrt(2 * mass * ke0)
        scale[f"mean_v{a}"] = v_scale
        scale[f"mean_a{a}"] = v_scale / 2e-4
    # An overlap is a difference of positions: its round-off is a position's (the scale of
    # mean_x, about half the box) over the diameter.
    for c in ("overlap_mean", "overlap_max", "wall_overlap_mean", "wall_overlap_max"):
        scale[c] = scale["mean_x"] / 100e-6
    worst = {}
    for r1, rn in zip(one, many):
        for c in r1:
            if c in SKIP:
                continue
            x, y = float(r1[c]), float(rn[c])
            if c in EXACT:
                assert x == y, f"{c}: {x} (1 rank) != {y} ({RANKS} ranks) at t = {r1['time']}"
                continue
            err = abs(x - y) / scale[c] if scale[c] > 0 else abs(x - y)
            worst[c] = max(worst.get(c, 0.0), err)
            assert err <= 1e-9, f"{c}: {x} vs {y} at t = {r1['time']} (scaled error {err:.3g})"
    assert info["ranks"] == RANKS and info["threads"] == 1, info
    assert len(info["mpi_wait_seconds"]) == RANKS, info["mpi_wait_seconds"]
    assert info["load_imbalance_max"] >= 1.0 and len(info["load_imbalance"]) >= 1
    assert sum(info["owned_particles_at_end"]) == 100
    if snap_one is not None:
        assert sorted(snap_one) == sorted(snap_many) and len(snap_one) == 3, (snap_one, snap_many)
        for name, a in snap_one.items():
            b = snap_many[name]
            assert (a["id"] == b["id"]).all(), name
            dx = abs(a["position"] - b["position"]).max()
            dv = abs(a["velocity"] - b["velocity"]).max()
            assert dx <= 1e-9 * 100e-6 and dv <= 1e-9 * v_scale, (name, dx, dv)
    print(f"{RANKS} ranks vs 1 {' '.join(extra)}: worst scaled column error "
          f"{max(worst.values()):.3g} ({max(worst, key=worst.get)}); "
          f"imbalance max {info['load_imbalance_max']:.3f}")


def loaded_contacts(path):
    try:
        import h5py
    except ImportError:
        return None
    with h5py.File(path, "r") as f:
        return len(f["neighbor_list/history_x"])


def restart_is_exact(extra, half):
    """2N steps on RANKS ranks vs N steps + checkpoint + restart + N steps on RANKS ranks: the
    diagnostics rows (all but wall_seconds) and the final snapshot (by id) are bitwise equal."""
    extra = extra + [f"output.checkpoint_interval={half}"]
    with tempfile.TemporaryDirectory() as tmp:
        full, half = os.path.join(tmp, "full"), os.path.join(tmp, "restarted")
        cmd = [MPIEXEC, "-np", str(RANKS), "--oversubscribe", CFDDEM, "run", SCENE]
        subprocess.run(cmd + ["--out", full] + ARGS + extra, check=True, env=ENV, timeout=120)
        cks = sorted(n for n in os.listdir(full) if n.startswith("checkpoint_"))
        assert len(cks) == 2, cks  # half way and at the end
        if FRICTION[0] in extra:
            loaded = loaded_contacts(os.path.join(full, cks[0]))
            assert loaded is None or loaded > 0, "no contact history in the checkpoint"
        subprocess.run(cmd + ["--out", half, "--restart", os.path.join(full, cks[0])] + ARGS + extra,
                       check=True, env=ENV, timeout=120)
        rows = []
        for d in (full, half):
            with open(os.path.join(d, "diagnostics.csv")) as f:
                rows.append([{k: v for k, v in r.items() if k not in SKIP} for r in csv.DictReader(f)])
        assert rows[0] == rows[1], "restarted diagnostics differ"
        a, b = snapshots(full), snapshots(half)
        if a is not None:
            last = sorted(a)[-1]
            for k in ("id", "position", "velocity"):
                assert (a[last][k] == b[last][k]).all(), (last, k)
        if FRICTION[0] in extra:
            # The same checkpoint on one rank (the serial scheme takes the history rows over):
            # the energy agrees to round-off, as between 1 and R ranks.
            one = os.path.join(tmp, "one")
            subprocess.run([CFDDEM, "run", SCENE, "--out", one, "--restart",
                            os.path.join(full, cks[0])] + ARGS + extra,
                           check=True, env=ENV, timeout=120)
            with open(os.path.join(one, "diagnostics.csv")) as f:
                ke = [float(r["kinetic_energy"]) for r in csv.DictReader(f)]
            ref = [float(r["kinetic_energy"]) for r in rows[0]]
            assert len(ke) == len(ref)
            assert max(abs(x - y) for x, y in zip(ke, ref)) <= 1e-9 * max(ref), (ke, ref)
    print(f"{RANKS} ranks {' '.join(extra)}: restart at {cks[0]} continues bit for bit "
          f"({len(rows[0])} rows)")


if __name__ == "__main__":
    main()
