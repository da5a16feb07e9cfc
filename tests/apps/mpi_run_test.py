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
import os
import sys
import tempfile

from mpi_rows import (compare_rows, hcs_scales, mpirun, outputs, particle_snapshots,
                      run_with_snapshots, without_wall_seconds, worst_of)

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
SCENE = os.path.join(SOURCE, "scenes", "hcs_small.toml")
ARGS = ["run.end_time=0.004", "output.interval=2e-4", "output.snapshot_interval=2e-3",
        "--threads", "1", "--quiet"]
EXACT = ["time", "step", "particles", "particle_steps", "force_evaluations", "neighbor_builds"]
SKIP = ["wall_seconds"]
# Denser, so chaos amplifies round-off faster: half the run time keeps it within the bound.
FRICTION = ["dem.friction=0.5", "domain.hi=[0.64e-3,0.64e-3,0.64e-3]", "run.end_time=0.002",
            "output.snapshot_interval=1e-3"]


def run(ranks, out, extra):
    return run_with_snapshots(MPIEXEC, ranks, CFDDEM, SCENE, out, ARGS + extra)


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
    scale = hcs_scales(one, 2e-4)
    v_scale = scale["mean_vx"]
    worst = compare_rows(one, many, scale, 1e-9, exact=EXACT, skip=SKIP,
                         label=f"{RANKS} ranks vs 1")
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
    print(f"{RANKS} ranks vs 1 {' '.join(extra)}: worst scaled column error {worst_of(worst)}; "
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
        mpirun(MPIEXEC, RANKS, CFDDEM, SCENE, full, ARGS + extra)
        cks = sorted(n for n in os.listdir(full) if n.startswith("checkpoint_"))
        assert len(cks) == 2, cks  # half way and at the end
        if FRICTION[0] in extra:
            loaded = loaded_contacts(os.path.join(full, cks[0]))
            assert loaded is None or loaded > 0, "no contact history in the checkpoint"
        mpirun(MPIEXEC, RANKS, CFDDEM, SCENE, half,
               ARGS + extra + ["--restart", os.path.join(full, cks[0])])
        rows = [without_wall_seconds(outputs(d)[0]) for d in (full, half)]
        assert rows[0] == rows[1], "restarted diagnostics differ"
        a, b = particle_snapshots(full), particle_snapshots(half)
        if a is not None:
            last = sorted(a)[-1]
            for k in ("id", "position", "velocity"):
                assert (a[last][k] == b[last][k]).all(), (last, k)
        if FRICTION[0] in extra:
            # The same checkpoint on one rank (the serial scheme takes the history rows over):
            # the energy agrees to round-off, as between 1 and R ranks.
            one = os.path.join(tmp, "one")
            mpirun(MPIEXEC, 1, CFDDEM, SCENE, one,
                   ARGS + extra + ["--restart", os.path.join(full, cks[0])])
            ke = [float(r["kinetic_energy"]) for r in outputs(one)[0]]
            ref = [float(r["kinetic_energy"]) for r in rows[0]]
            assert len(ke) == len(ref)
            assert max(abs(x - y) for x, y in zip(ke, ref)) <= 1e-9 * max(ref), (ke, ref)
    print(f"{RANKS} ranks {' '.join(extra)}: restart at {cks[0]} continues bit for bit "
          f"({len(rows[0])} rows)")


if __name__ == "__main__":
    main()
