#!/usr/bin/env python3
"""Checkpoint and restart of a gas-particle run on R ranks (apps/coupled_checkpoint.hpp).

Usage: mpi_coupled_restart_test.py MPIEXEC CFDDEM SOURCE_DIR RANKS [SCHEME]

SCHEME orb or islands (dem.nsubit = 10): the same checks but friction (they refuse it) and the
bad-input ones (the scheme does not enter them); their file holds save_state()'s per-particle
values, and the routed copies deposit in id order, so the restart is again bit for bit.
orb_global: orb with its global mode on R ranks (dem.orb_global_min_per_rank = 0), which keeps
its rows and ghosts over the global sub-iterations of a fluid step (OrbScheme::rank_keep_rows)
and rebuilds them at the next: the run kept rows, and the restart on R ranks continues bit for
bit (only that: the other rank counts are MpiRun.CoupledOrbGlobalRiserMatchesOneRank's).

The small periodic riser of mpi_coupled_test.py (800 particles that migrate between ranks,
12 x 20 x 12 cells), 2N = 20 fluid steps with a checkpoint after N:
  - restarted on R ranks, the other N steps give the 2N run's diagnostics rows (all but
    wall_seconds) and final snapshot (particles by id, gas cells) bit for bit; restarted from the
    2N run's last checkpoint with the same end time, the last row again (the held gas force);
  - restarted on 1 rank and on R + 1 ranks (the gas fields are whole-grid datasets, read back
    by any cutting into boxes), the same to round-off (1e-12 of each column's scale, the
    snapshot's particles and cells likewise). Not compared there: neighbor_builds and
    force_evaluations (the serial scheme rebuilds its list at a restart and counts pairs its own
    way) and mean_x/y/z (positions are unwrapped between list builds, so a particle that crossed
    the periodic boundary counts at either end until the next build);
  - a checkpoint written on 1 rank restarts on R ranks, to round-off against the R-rank run;
  - with friction (dem.friction = 0.3, the particles denser and hotter so that the checkpoint
    holds open contacts) the spin and the contact history travel in the file: the restart on R
    ranks is again bit for bit;
  - with gas regrids (partition.gas_regrid_interval, the particles in the lower 40 % so that the
    boxes are recut and moved before the checkpoint) the file holds the gas from the recut
    boxes and the boxes themselves; the restart goes on from those boxes and regrids when the
    run did, from the checkpoint's time on (its last fluid step's particle steps are in the
    file): bit for bit, and its regrids are the run's. Again where the first regrid falls on
    the checkpoint's time and moves the boxes (the run wrote the checkpoint, then recut);
  - refused with exit code 2, naming the file and what differs: another gas grid, and a gas
    field changed in the file (the checksum, summed over the ranks' boxes).
"""
import csv
import os
import subprocess
import sys
import tempfile

import h5py
import numpy as np
from mpi_rows import mpirun, outputs

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
SCHEME = sys.argv[5] if len(sys.argv) > 5 else "explicit"
SUB = SCHEME != "explicit"  # orb or islands: frictionless, their save_state() in the file
SCENE = os.path.join(SOURCE, "scenes", "riser.toml")
ARGS = ["domain.hi=[2.4e-3,4.0e-3,2.4e-3]", "particles.count=800", "particles.temperature=1e-4",
        "fluid.cells=[12,20,12]", "output.interval=2e-4", "output.snapshot_interval=1e-3",
        "output.checkpoint_interval=1e-3", "--threads", "1", "--quiet"]
# 1 and R ranks solve the projection with the multigrid (fluid.solver = "auto"), which agrees
# with itself over the ranks to round-off (1e-12 of gas_mass_residual's scale is below the
# solver tolerance by which it and hypre differ); hypre on R ranks:
# tests/fluid/distributed_gas_test.cpp.
if SUB:
    ARGS += [f"dem.scheme={SCHEME.removesuffix('_global')}", "dem.nsubit=10"]
if SCHEME == "orb_global":
    ARGS += ["dem.orb_global_min_per_rank=0"]
if SCHEME == "orb":  # R ranks take the leaf steps: so does the one-rank run they must equal
    ARGS += ["dem.orb_global=false"]
# Denser and hotter, so that contacts (and their tangential history) are open at the checkpoint.
FRICTION_ARGS = ["dem.friction=0.3", "particles.temperature=1e-2",
                 "particles.region_hi=[2.4e-3,0.6e-3,2.4e-3]"]
CONVENTIONS = ["wall_seconds", "neighbor_builds", "force_evaluations", "mean_x", "mean_y",
               "mean_z"]
if SCHEME == "islands":
    # Work, not state: an island spanning ranks takes every fine step after its lead, where one
    # rank folds the island's contact-free stretches into one step (islands_kernels.hpp,
    # free_time), so the steps taken depend on the rank counts a run went through. The same rank
    # count restarts bit for bit, these counts included (assert_bitwise).
    CONVENTIONS += ["particle_steps"]


def run(ranks, out, *extra, check=True):
    return mpirun(MPIEXEC, ranks, CFDDEM, SCENE, out, ARGS + list(extra), check=check,
                  capture=not check)


def rows(d, skip=("wall_seconds",)):
    with open(os.path.join(d, "diagnostics.csv")) as f:
        return [{k: float(v) for k, v in r.items() if k not in skip} for r in csv.DictReader(f)]


def snapshot(d):
    last = max(n for n in os.listdir(d) if n.startswith("snapshot_") and n.endswith(".h5"))
    with h5py.File(os.path.join(d, last)) as f:
        order = np.argsort(f["particles/id"][()])
        return {f"{g}/{k}": f[g][k][()][order] if g == "particles" else f[g][k][()]
                for g in ("particles", "fluid") for k in f[g]}


def regrids(d):
    return outputs(d)[1]["gas_regrids"]


def assert_bitwise(a, b, what):
    assert rows(a) == rows(b), f"{what}: diagnostics rows differ"
    sa, sb = snapshot(a), snapshot(b)
    for k in sa:
        assert np.array_equal(sa[k], sb[k]), f"{what}: {k} differs"


def assert_round_off(a, b, what):
    ra, rb = rows(a, CONVENTIONS), rows(b, CONVENTIONS)
    assert len(ra) == len(rb), (what, len(ra), len(rb))
    scale = {c: max(abs(r[c]) for r in ra) for c in ra[0]}
    for kind in ("momentum_", "gas_momentum_", "mean_v", "mean_a"):
        for x in "xz":
            scale[kind + x] = max(scale[kind + x], scale[kind + "y"])
    scale["gas_mass_residual"] = 1.0  # a round-off quantity itself (< 1e-8, mpi_coupled_test)
    for x, y in zip(ra, rb):
        for c in x:
            err = abs(x[c] - y[c]) / (scale[c] or 1.0)
            assert err <= 1e-12, f"{what}: {c} {x[c]} vs {y[c]} at t = {x['time']} ({err:.3g})"
    sa, sb = snapshot(a), snapshot(b)
    assert np.array_equal(sa["particles/id"], sb["particles/id"]), what
    for k in sa:
        if SCHEME == "islands" and k in ("particles/leaf", "particles/local_dt"):
            continue  # island labels, and fine or free steps near a rank boundary, differ
        err = np.max(np.abs(sa[k] - sb[k])) / max(np.max(np.abs(sa[k])), 1e-300)
        assert err <= 1e-12, f"{what}: {k} scaled difference {err:.3g}"


def main():
    with tempfile.TemporaryDirectory() as tmp:
        d = {k: os.path.join(tmp, k) for k in ("full", "half", "end", "one", "more", "first",
                                               "from_one", "bad", "fric", "fric_half",
                                               "regrid", "regrid_at")}
        run(RANKS, d["full"], "run.end_time=2e-3")
        cks = sorted(n for n in os.listdir(d["full"]) if n.startswith("checkpoint_"))
        assert cks == ["checkpoint_000000010.h5", "checkpoint_000000020.h5"], cks
        mid = os.path.join(d["full"], cks[0])
        run(RANKS, d["half"], "run.end_time=2e-3", "--restart", mid)
        assert_bitwise(d["full"], d["half"], f"restart on {RANKS} ranks")
        if SCHEME == "orb_global":  # 20 fluid steps of 10 sub-iterations, some global
            info = outputs(d["full"])[1]
            assert info["global_subiterations"] > 0, info["global_subiterations"]
            assert info["neighbor_builds"] < 200, ("no rows kept", info["neighbor_builds"])
            # Other rank counts: MpiRun.CoupledOrbGlobalRiserMatchesOneRank (CI time kept short).
            return print(f"orb's global mode, {RANKS} ranks: rows kept "
                         f"({info['neighbor_builds']} builds), restart at {cks[0]} continues bit "
                         f"for bit")
        run(RANKS, d["end"], "run.end_time=2e-3", "--restart", os.path.join(d["full"], cks[1]))
        assert rows(d["end"]) == rows(d["full"]), "restart at the end time: last row differs"
        # Other rank counts read the same file.
        run(1, d["one"], "run.end_time=2e-3", "--restart", mid)
        assert_round_off(d["full"], d["one"], f"{RANKS}-rank checkpoint on 1 rank")
        run(RANKS + 1, d["more"], "run.end_time=2e-3", "--restart", mid)
        assert_round_off(d["full"], d["more"], f"{RANKS}-rank checkpoint on {RANKS + 1} ranks")
        run(1, d["first"], "run.end_time=1e-3")
        run(RANKS, d["from_one"], "run.end_time=2e-3", "--restart",
            os.path.join(d["first"], cks[0]))
        assert_round_off(d["full"], d["from_one"], f"1-rank checkpoint on {RANKS} ranks")
        # Friction (explicit only): spin and contact history in the file, bitwise again.
        if not SUB:
            fric = ["run.end_time=2e-3"] + FRICTION_ARGS
            run(RANKS, d["fric"], *fric)
            run(RANKS, d["fric_half"], *fric, "--restart", os.path.join(d["fric"], cks[0]))
            assert_bitwise(d["fric"], d["fric_half"], f"frictional restart on {RANKS} ranks")
        # Gas regrids: the checkpoint written from recut boxes (every 5e-4 s: one regrid before
        # the checkpoint, one at its time), then one whose first regrid comes at its time.
        for every, name in (("5e-4", "regrid"), ("1e-3", "regrid_at")):
            regrid = ["run.end_time=2e-3", "particles.region_hi=[2.4e-3,1.6e-3,2.4e-3]",
                      f"partition.gas_regrid_interval={every}"]
            if SUB:  # each particle weighs only its dem.nsubit sub-iterations: lighter cells
                regrid += ["partition.cell_weight=0.5"]
            run(RANKS, d[name], *regrid)
            done = regrids(d[name])
            moved = [g["time"] for g in done if g["moved"]]
            if name == "regrid":
                assert moved and moved[0] < 1e-3 - 1e-9, done
            else:
                assert moved and abs(moved[0] - 1e-3) < 1e-9, done
            half = d[name] + "_half"
            run(RANKS, half, *regrid, "--restart", os.path.join(d[name], cks[0]))
            assert_bitwise(d[name], half, f"restart with gas regrids every {every} s")
            later = [g for g in done if g["time"] > 1e-3 - 1e-9]
            drop = ("imbalance_before", "imbalance_after", "moved", "gas_values_sent", "time")
            assert [[g[k] for k in drop] for g in regrids(half)] == \
                [[g[k] for k in drop] for g in later], (regrids(half), later)
        if SUB:
            return print(f"{SCHEME}, {RANKS} ranks: restart at {cks[0]} continues bit for bit, "
                         f"with gas regrids too; on 1 and {RANKS + 1} ranks and a 1-rank one on "
                         f"{RANKS} to round-off")
        # Bad input: another grid; a gas field changed after writing.
        r = run(RANKS, d["bad"], "run.end_time=2e-3", "fluid.cells=[12,20,6]", "--restart", mid,
                check=False)
        assert r.returncode == 2 and mid in r.stderr and "fluid.cells" in r.stderr, r.stderr
        bad = os.path.join(tmp, "changed.h5")
        subprocess.run(["cp", mid, bad], check=True)
        with h5py.File(bad, "r+") as f:
            f["gas/p"][3, 7, 5] += 1e-9
        r = run(RANKS, d["bad"], "run.end_time=2e-3", "--restart", bad, check=False)
        assert r.returncode == 2 and bad in r.stderr and "gas fields are corrupt" in r.stderr, \
            r.stderr
    print(f"{RANKS} ranks: restart at {cks[0]} continues bit for bit; the checkpoint restarts on "
          f"1 and {RANKS + 1} ranks, and a 1-rank one on {RANKS}, to round-off; with friction and "
          f"with gas regrids bit for bit")


if __name__ == "__main__":
    main()
