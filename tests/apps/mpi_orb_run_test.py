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
import csv
import json
import math
import os
import subprocess
import sys
import tempfile

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
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
EXACT = ["time", "step", "particles", "particle_steps", "leaf_steps_min", "leaf_steps_mean",
         "leaf_steps_max", "fine_leaf_fraction"]
SKIP = ["wall_seconds", "force_evaluations", "neighbor_builds"]


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
                order = p["id"][()].argsort()
                found[name] = {k: p[k][()][order] for k in ("id", "position", "velocity")}
    return found


def run(ranks, out, extra=()):
    cmd = [MPIEXEC, "-np", str(ranks), "--oversubscribe", CFDDEM, "run", SCENE, "--out", out]
    subprocess.run(cmd + ARGS + list(extra), check=True, env=ENV, timeout=120)
    with open(os.path.join(out, "diagnostics.csv")) as f:
        rows = list(csv.DictReader(f))
    with open(os.path.join(out, "run.json")) as f:
        info = json.load(f)
    return rows, info, snapshots(out)


def compare_rows(one, many, scale, tol):
    """The EXACT columns equal, the others (SKIP aside) within tol of their scale (absolutely
    where the scale is 0); returns the worst scaled difference per column."""
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
            assert err <= tol, f"{c}: {x} vs {y} at t = {r1['time']} (scaled error {err:.3g})"
    return worst


def matches_one_rank():
    with tempfile.TemporaryDirectory() as tmp:
        one, _, snap_one = run(1, os.path.join(tmp, "np1"))
        many, info, snap_many = run(RANKS, os.path.join(tmp, f"np{RANKS}"))
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
    worst = compare_rows(one, many, scale, 1e-12)
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
          f"{max(worst.values()):.3g} ({max(worst, key=worst.get)})")


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
    scale = {c: max(abs(float(r[c])) for r in one) for c in one[0]}
    worst = max(compare_rows(one, many, scale, 1e-10).values())
    print(f"orb held global mode, {RANKS} ranks vs 1: {i1['regrids']} regrids of {points} "
          f"points, {i1['global_subiterations']} global sub-iterations on both; worst scaled "
          f"diagnostics difference {worst:.3g}")


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
        rows = []
        for d in (full, half):
            with open(os.path.join(d, "diagnostics.csv")) as f:
                rows.append([{k: v for k, v in r.items() if k != "wall_seconds"}
                             for r in csv.DictReader(f)])
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
        cmd = [MPIEXEC, "-np", str(RANKS), "--oversubscribe", CFDDEM, "run", SCENE, "--out", tmp,
               "dem.scheme=orb", "dem.nsubit=1", "dem.regrid_interval=5e-4",
               "particles.temperature=1.0", "run.end_time=0.01", "--threads", "1", "--quiet"]
        r = subprocess.run(cmd, env=ENV, timeout=60, capture_output=True, text=True)
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
