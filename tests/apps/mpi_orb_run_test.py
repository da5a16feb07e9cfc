#!/usr/bin/env python3
"""`mpirun -np R cfddem run` with dem.scheme = "orb" against the 1-rank (serial OrbScheme) run,
and its checkpoint/restart on R ranks.

Usage: mpi_orb_run_test.py MPIEXEC CFDDEM SOURCE_DIR RANKS [friction|held]

With `friction` the same comparisons with dem.friction = 0.5 in a denser gas (the box shrunk to
0.64 mm, 20% solids, over 2 ms, so that contacts are alive at the checkpoint): tangential
springs with history routed with their particles, spins on the ghosts, both in the checkpoint.
The failure case is left out.

The distributed orb scheme takes the serial ORB's leaves and sums every particle's row in the
serial order, so the particles' states are the serial ones bit for bit: the snapshots (by id)
are compared exactly. The diagnostics are sums over the ranks' partial sums (another order), so
their state columns agree to round-off: 1e-12 of the column's scale (the thermal scales for
quantities that are zero up to round-off), far above the few ulps a 100-particle sum can differ
by, far below any real difference. Work counters that do not depend on the lists (time, step,
particles, particle steps, leaf steps, fine-leaf fraction) agree exactly; force evaluations and
neighbor builds are counted over this scheme's own lists (rebuilt each sub-iteration) and are
not compared. Then 2N sub-iterations on R ranks vs N + checkpoint + restart + N on R ranks:
diagnostics (all but wall_seconds) and the final snapshot bitwise equal; the same checkpoint
restarted on one rank ends with the same particles bit for bit. A failing run stops every rank
with exit code 3 and one message.

With `held`, orb's global mode held over regrid points instead: HCS 1222 at the paper's settings
(dem.nsubit = 15, 64 leaves) with dem.proximity_radii = 2.8, where the share of particles in
fine leaves lies near 3/4, so the global mode holds over most regrid points, which then decide
on the leaves as they are and cut no new ORB, and is left at some (dem.orb_global_min_per_rank
= 0: R ranks take it too). One rank decides a held regrid point without the proximity
candidates (OrbScheme::held_global_decision), R ranks from their rows' proximity flags: the
decisions must be the same, so the regrids, the global sub-iterations and every work counter
that does not depend on the lists agree exactly, and the state columns to round-off (the global
steps sum in another order on R ranks): 1e-10 of the column's scale over 4 ms, far below a
physical difference. The restart, from a checkpoint inside a held interval, as above.
"""
import os
import sys
import tempfile

from mpi_rows import (compare_rows, column_scales, hcs_scales, mpirun, outputs,
                      run_with_snapshots, without_wall_seconds, worst_of)

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
FRICTION = len(sys.argv) > 5 and sys.argv[5] == "friction"
HELD = len(sys.argv) > 5 and sys.argv[5] == "held"
SCENE = os.path.join(SOURCE, "scenes", "hcs_small.toml")
# R ranks take the leaf steps; the one-rank run they must equal does too (dem.orb_global).
ARGS = ["dem.scheme=orb", "dem.orb_global=false", "run.end_time=0.004", "output.interval=2e-4",
        "output.snapshot_interval=2e-3", "--threads", "1", "--quiet"]
CHECKPOINT = "2e-3"
if FRICTION:
    ARGS += ["dem.friction=0.5", "domain.hi=[0.64e-3,0.64e-3,0.64e-3]", "run.end_time=0.002",
             "output.snapshot_interval=1e-3"]
    CHECKPOINT = "1e-3"
if HELD:
    SCENE = os.path.join(SOURCE, "scenes", "hcs.toml")
    ARGS = ["dem.scheme=orb", "dem.nsubit=15", "partition.orb_levels=6",
            "dem.proximity_radii=2.8", "dem.orb_global_min_per_rank=0", "run.end_time=0.004",
            "output.interval=2e-4", "--threads", "1", "--quiet"]
EXACT = ["time", "step", "particles", "particle_steps", "leaf_steps_min", "leaf_steps_mean",
         "leaf_steps_max", "fine_leaf_fraction"]
SKIP = ["wall_seconds", "force_evaluations", "neighbor_builds"]


def run(ranks, out, extra=()):
    return run_with_snapshots(MPIEXEC, ranks, CFDDEM, SCENE, out, ARGS + list(extra))


def compare(one, many, scale, tol):
    return compare_rows(one, many, scale, tol, exact=EXACT, skip=SKIP,
                        label=f"{RANKS} ranks vs 1")


def matches_one_rank():
    with tempfile.TemporaryDirectory() as tmp:
        one, _, snap_one = run(1, os.path.join(tmp, "np1"))
        many, info, snap_many = run(RANKS, os.path.join(tmp, f"np{RANKS}"))
    assert len(one) == len(many) > 10, (len(one), len(many))
    scale = hcs_scales(one, 2e-4)
    worst = compare(one, many, scale, 1e-12)
    fine = [float(r["fine_leaf_fraction"]) for r in one[1:]]
    # The run collides, not everywhere at once (the denser frictional gas: every leaf fine).
    assert 0 < max(fine) and (FRICTION or min(fine) < 1), fine
    assert info["ranks"] == RANKS and info["threads"] == 1 and info["scheme"] == "orb", info
    assert info["distributed"] is True
    assert len(info["mpi_wait_seconds"]) == RANKS, info["mpi_wait_seconds"]
    assert sum(info["owned_particles_at_end"]) == 100
    assert info["force_evaluations"] > 0 and 0 < info["fine_leaf_fraction_mean"], info
    assert FRICTION or info["fine_leaf_fraction_mean"] < 1, info
    if snap_one is not None:
        assert sorted(snap_one) == sorted(snap_many) and len(snap_one) == 3, (snap_one, snap_many)
        for name, a in snap_one.items():
            b = snap_many[name]
            for k in ("id", "position", "velocity"):
                assert (a[k] == b[k]).all(), (name, k, abs(a[k] - b[k]).max())
    print(f"orb, {RANKS} ranks vs 1: snapshots bitwise equal; worst scaled diagnostics error "
          f"{worst_of(worst)}")


def held_matches_one_rank():
    with tempfile.TemporaryDirectory() as tmp:
        one, i1, _ = run(1, os.path.join(tmp, "np1"))
        many, ir, _ = run(RANKS, os.path.join(tmp, f"np{RANKS}"))
    points = round(0.004 / 1e-4) + 1  # regrid points: one every dem.nsubit sub-iterations
    for k in ("regrids", "global_subiterations", "steps", "particle_steps"):
        assert i1[k] == ir[k], f"{k}: {i1[k]} (1 rank) != {ir[k]} ({RANKS} ranks)"
    assert 1 < i1["regrids"] < points, i1["regrids"]  # some points kept the ORB, some cut one
    assert 0 < i1["global_subiterations"] < i1["steps"] - 1, i1["global_subiterations"]
    assert len(one) == len(many) > 10, (len(one), len(many))
    worst = compare(one, many, column_scales(one), 1e-10)
    print(f"orb held global mode, {RANKS} ranks vs 1: {i1['regrids']} regrids of {points} "
          f"points, {i1['global_subiterations']} global sub-iterations on both; worst scaled "
          f"diagnostics difference {worst_of(worst)}")


def restart_is_exact():
    extra = [f"output.checkpoint_interval={CHECKPOINT}"]
    with tempfile.TemporaryDirectory() as tmp:
        full, half = os.path.join(tmp, "full"), os.path.join(tmp, "restarted")
        _, _, a = run(RANKS, full, extra)
        cks = sorted(n for n in os.listdir(full) if n.startswith("checkpoint_"))
        assert len(cks) == 2, cks  # half way and at the end
        if FRICTION:  # contacts alive at the checkpoint: its history has records
            import h5py
            with h5py.File(os.path.join(full, cks[0]), "r") as f:
                assert f["orb/history_x"].shape[0] > 0 and f.attrs["rotation"] == 1
        if HELD and a is not None:  # h5py is there: the checkpoint falls inside a held interval
            import h5py
            with h5py.File(os.path.join(full, cks[0]), "r") as f:
                assert "held_cut_axis" in f["orb"], "the checkpoint is not inside a held interval"
        _, _, b = run(RANKS, half, extra + ["--restart", os.path.join(full, cks[0])])
        rows = [without_wall_seconds(outputs(d)[0]) for d in (full, half)]
        assert len(rows[0]) > 10 and rows[0] == rows[1], "restarted diagnostics differ"
        if a:  # snapshots, read where h5py is installed
            last = sorted(a)[-1]
            for k in ("id", "position", "velocity"):
                assert (a[last][k] == b[last][k]).all(), (last, k)
            # The checkpoint holds no trace of the rank count: restarted on one rank (the serial
            # OrbScheme), the particles end bitwise where the R-rank run put them.
            _, _, c = run(1, os.path.join(tmp, "one"), extra + ["--restart", os.path.join(full, cks[0])])
            for k in ("id", "position", "velocity"):
                assert (a[last][k] == c[last][k]).all(), (last, k, "restarted on 1 rank")
    also = "; on 1 rank, the same final particles" if a else ""
    print(f"orb, {RANKS} ranks: restart at {cks[0]} continues bit for bit ({len(rows[0])} rows"
          f"{also})")


def failure_stops_every_rank():
    """A sub-iteration too long for the skin (a particle outruns even the largest skin) stops the
    R-rank run with exit code 3 and one message, well within the timeout (no rank left waiting)."""
    with tempfile.TemporaryDirectory() as tmp:
        r = mpirun(MPIEXEC, RANKS, CFDDEM, SCENE, tmp,
                   ["dem.scheme=orb", "dem.nsubit=1", "dem.regrid_interval=5e-4",
                    "particles.temperature=1.0", "run.end_time=0.01", "--threads", "1",
                    "--quiet"], check=False, capture=True, timeout=60)
    assert r.returncode == 3, (r.returncode, r.stderr[-2000:])
    assert r.stderr.count("cfddem: run stopped:") == 1, r.stderr[-2000:]
    assert "raise dem.nsubit" in r.stderr, r.stderr[-2000:]
    print(f"orb, {RANKS} ranks: a failing run stops with exit code 3 and one message")


if __name__ == "__main__":
    if HELD:
        held_matches_one_rank()
    else:
        matches_one_rank()
    restart_is_exact()
    if not FRICTION and not HELD:
        failure_stops_every_rank()
