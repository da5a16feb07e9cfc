#!/usr/bin/env python3
"""`mpirun -np R cfddem run` with dem.scheme = "islands" against the 1-rank (serial IslandsScheme)
run.

Usage: mpi_islands_run_test.py MPIEXEC CFDDEM SOURCE_DIR RANKS [friction]

With `friction` the same comparisons and restarts with dem.friction = 0.5 in a denser gas (the
box shrunk to 0.64 mm, 20% solids, over 2 ms with the checkpoint at 1.03 ms, so that contacts
are alive at the checkpoint; this gas is more chaotic, so shorter): tangential springs with history routed with their particles,
spins on the ghosts, both in the R-rank checkpoint (auto_length() is left out).

The distributed islands scheme sums a spanning island's forces in another order, and a particle
whose island spans ranks takes the fine steps where the serial scheme may fly it free (equal
under a constant force only to round-off), so the diagnostics' state columns agree to
round-off: 1e-10 of the column's scale (the thermal scales for quantities that are zero up to
round-off). The gas is chaotic: the relative difference of the temperature grows about tenfold
every 2 ms (measured: 6e-14 at 8 ms, 1e-12 at 10 ms, 1e-10 at 20 ms, 1e-7 at 30 ms, the same
on 2 and 3 ranks), so the run stops at 10 ms, a hundredfold below the bound, which is far below
a real difference (one missed collision changes the kinetic energy by percent). time, step and
particles agree exactly; work counters (particle steps, pairs, builds, fine fractions) count
another classification and are not compared. run.json says how often islands spanned ranks
(some do on R > 1 ranks) and no bound was violated. Checkpoints: restarts(). 
"""
import os
import sys
import tempfile

from mpi_rows import (compare_rows, hcs_scales, outputs, particle_snapshots, run_rows,
                      without_wall_seconds, worst_of)

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
SCENE = os.path.join(SOURCE, "scenes", "hcs_small.toml")
ARGS = ["dem.scheme=islands", "dem.nsubit=10", "run.end_time=0.01", "output.interval=5e-4", "--threads", "1",
        "--quiet"]
FRICTION = len(sys.argv) > 5 and sys.argv[5] == "friction"
END, CHECKPOINT, SNAPSHOTS, CK_NAME = "0.01", "5.03e-3", "5e-3", "checkpoint_000000503.h5"
if FRICTION:
    END, CHECKPOINT, SNAPSHOTS, CK_NAME = "0.002", "1.03e-3", "1e-3", "checkpoint_000000103.h5"
    ARGS[ARGS.index("run.end_time=0.01")] = f"run.end_time={END}"
    ARGS[ARGS.index("output.interval=5e-4")] = "output.interval=1e-4"
    ARGS += ["dem.friction=0.5", "domain.hi=[0.64e-3,0.64e-3,0.64e-3]"]
EXACT = ["time", "step", "particles"]
SKIP = ["wall_seconds", "particle_steps", "force_evaluations", "neighbor_builds",
        "leaf_steps_min", "leaf_steps_mean", "leaf_steps_max", "fine_leaf_fraction"]


def run(ranks, out, extra=()):
    return run_rows(MPIEXEC, ranks, CFDDEM, SCENE, out, ARGS + list(extra))


def compare(one, many, what):
    """The rows' state columns within 1e-10 of each column's scale; returns the worst."""
    assert len(one) == len(many) > 10, (len(one), len(many))
    return compare_rows(one, many, hcs_scales(one, 5e-4), 1e-10, exact=EXACT, skip=SKIP,
                        label=what)


def matches_one_rank():
    with tempfile.TemporaryDirectory() as tmp:
        one, info_one = run(1, os.path.join(tmp, "np1"))
        many, info = run(RANKS, os.path.join(tmp, f"np{RANKS}"))
    worst = worst_of(compare(one, many, f"{RANKS} ranks vs 1"))
    ke0 = float(one[0]["kinetic_energy"])
    # The gas cools: collisions happened (a run without any would pass trivially).
    assert float(one[-1]["kinetic_energy"]) < 0.99 * ke0, (one[-1]["kinetic_energy"], ke0)
    assert info["ranks"] == RANKS and info["threads"] == 1 and info["scheme"] == "islands", info
    assert info["distributed"] is True
    assert len(info["mpi_wait_seconds"]) == RANKS, info["mpi_wait_seconds"]
    assert sum(info["owned_particles_at_end"]) == 100
    assert info["bound_violations"] == 0 and info_one["bound_violations"] == 0, info
    if RANKS > 1:
        assert 0 < info["spanning_subiterations"] < info["steps"], info
    print(f"islands, {RANKS} ranks vs 1: worst scaled diagnostics error {worst}; islands "
          f"spanned ranks in "
          f"{info['spanning_subiterations']} of {info['steps']} sub-iterations")


def last_snapshot(out):
    snaps = particle_snapshots(out)
    if snaps is None:
        raise ImportError("h5py: the restarts compare the final snapshots")
    name = max(snaps)
    return name, snaps[name]


def restarts():
    """2N sub-iterations on R ranks with a checkpoint after N vs the restart from it: the rows
    (all but wall_seconds) and the final snapshot bit for bit. The R-rank checkpoint restarted
    on one rank (the serial scheme) and a 1-rank checkpoint restarted on R ranks: the rows
    within the 1-rank comparison's bound of the run that wrote the checkpoint."""
    # 5.03 ms: between two of the run's own builds (about every 10 sub-iterations here), so the
    # restart's fresh build is one the run that wrote it must make too (save_state).
    extra = [f"output.checkpoint_interval={CHECKPOINT}", f"output.snapshot_interval={SNAPSHOTS}"]
    with tempfile.TemporaryDirectory() as tmp:
        d = {k: os.path.join(tmp, k) for k in ("full", "half", "one", "full1", "from1")}
        full, info = run(RANKS, d["full"], extra)
        cks = sorted(n for n in os.listdir(d["full"]) if n.startswith("checkpoint_"))
        assert cks == [CK_NAME], cks  # dt_sp = 10 us
        mid = os.path.join(d["full"], cks[0])
        half, _ = run(RANKS, d["half"], extra + ["--restart", mid])
        assert len(full) > 10 and without_wall_seconds(full) == without_wall_seconds(half), \
            "restarted diagnostics differ"
        na, a = last_snapshot(d["full"])
        nb, b = last_snapshot(d["half"])
        assert na == nb, (na, nb)
        for k in a:
            assert (a[k] == b[k]).all(), (na, k, "restarted snapshot differs")
        half_info = outputs(d["half"])[1]
        assert half_info["spanning_subiterations"] == info["spanning_subiterations"] or RANKS == 1
        # Across rank counts: one rank from the R-rank file, R ranks from a 1-rank file.
        one, _ = run(1, d["one"], extra + ["--restart", mid])
        worst_one = worst_of(compare(full, one, f"{RANKS}-rank checkpoint restarted on 1 rank"))
        full1, _ = run(1, d["full1"], extra)
        from1, _ = run(RANKS, d["from1"], extra + ["--restart", os.path.join(d["full1"], cks[0])])
        worst_from1 = worst_of(
            compare(full1, from1, f"1-rank checkpoint restarted on {RANKS} ranks"))
    print(f"islands, {RANKS} ranks: restart at {cks[0]} continues bit for bit; on 1 rank "
          f"{worst_one}, a 1-rank checkpoint on {RANKS} ranks {worst_from1}")


def auto_length():
    """dem.nsubit = "auto": every rank takes the choice from counts summed over the ranks, with
    the ghosts where their owners have them, so R ranks choose what one rank chooses (the same
    log in run.json, the same force evaluations) and the rows agree as without "auto"; a
    restart from the R-rank checkpoint goes on bit for bit."""
    extra = ["dem.nsubit=auto"]
    with tempfile.TemporaryDirectory() as tmp:
        one, info_one = run(1, os.path.join(tmp, "np1"), extra)
        many, info = run(RANKS, os.path.join(tmp, f"np{RANKS}"), extra)
        worst = worst_of(compare(one, many, f"auto: {RANKS} ranks vs 1"))
        picks = lambda i: [(c["t"], c["nsubit"], c["intervals"]) for c in i["nsubit_choices"]]
        assert picks(info) == picks(info_one), (picks(info), picks(info_one))
        assert len(picks(info)) >= 2, picks(info)
        assert info["bound_violations"] == 0 and info_one["bound_violations"] == 0
        ck = ["output.checkpoint_interval=5e-3"]
        full, _ = run(RANKS, os.path.join(tmp, "full"), extra + ck)
        mid = os.path.join(tmp, "full", "checkpoint_000000050.h5")
        half, info_half = run(RANKS, os.path.join(tmp, "half"), extra + ck + ["--restart", mid])
        assert without_wall_seconds(full) == without_wall_seconds(half), \
            "auto: restarted diagnostics differ"
        assert picks(info_half) == picks(info), "auto: restarted choices differ"
    print(f"islands auto, {RANKS} ranks vs 1: the same {len(picks(info))} choices, worst scaled "
          f"diagnostics error {worst}; restart bit for bit")


if __name__ == "__main__":
    matches_one_rank()
    restarts()
    if not FRICTION:
        auto_length()
