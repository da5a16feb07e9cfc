"""What the MPI test scripts share: `cfddem run` on R ranks with its outputs read back, and the
comparison of an R-rank run's diagnostics rows with the one-rank run's.

The scripts beside this file import it (a script's own folder is first on sys.path).
"""
import csv
import json
import math
import os
import subprocess

# Open MPI refuses to run as root unless told (the CI machines run as root).
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def mpirun(mpiexec, ranks, cfddem, scene, out, args, check=True, capture=False, timeout=120):
    """`mpiexec -np RANKS cfddem run SCENE --out OUT ARGS`; the CompletedProcess."""
    cmd = [mpiexec, "-np", str(ranks), "--oversubscribe", cfddem, "run", scene, "--out", out]
    return subprocess.run(cmd + list(args), check=check, env=ENV, timeout=timeout,
                          capture_output=capture, text=capture)


def outputs(out):
    """diagnostics.csv's rows (strings, as csv reads them) and run.json of a run's folder."""
    with open(os.path.join(out, "diagnostics.csv")) as f:
        rows = list(csv.DictReader(f))
    with open(os.path.join(out, "run.json")) as f:
        info = json.load(f)
    return rows, info


def run_rows(mpiexec, ranks, cfddem, scene, out, args):
    """mpirun, then outputs(out)."""
    mpirun(mpiexec, ranks, cfddem, scene, out, args)
    return outputs(out)


def run_with_snapshots(mpiexec, ranks, cfddem, scene, out, args):
    """run_rows, and the particle_snapshots of the run (None without h5py)."""
    rows, info = run_rows(mpiexec, ranks, cfddem, scene, out, args)
    return rows, info, particle_snapshots(out)


def without_wall_seconds(rows):
    """The rows with the one column that differs between two equal runs left out."""
    return [{k: v for k, v in r.items() if k != "wall_seconds"} for r in rows]


def particle_snapshots(out):
    """Every snapshot's particles (id, position, velocity) in id order, by file name; None
    where h5py is not installed (the MPI tests then check the rows alone)."""
    try:
        import h5py
    except ImportError:
        return None
    found = {}
    for name in sorted(os.listdir(out)):
        if name.startswith("snapshot_") and name.endswith(".h5"):
            with h5py.File(os.path.join(out, name), "r") as f:
                p = f["particles"]
                order = p["id"][()].argsort()  # a store's order is its scheme's, not the ids'
                found[name] = {k: p[k][()][order] for k in ("id", "position", "velocity")}
    return found


def column_scales(one):
    """Each column's largest magnitude over the one-rank rows."""
    return {c: max(abs(float(r[c])) for r in one) for c in one[0]}


def hcs_scales(one, interval, count=100, diameter=100e-6, density=1000.0):
    """column_scales, with the thermal scales of a homogeneous cooling gas for the columns that
    are zero up to round-off: momentum sqrt(2 M KE0), mean velocity sqrt(2 KE0 / M), mean
    acceleration that over the output interval; and an overlap's, which is a difference of
    positions: a position's (mean_x, about half the box) over the diameter."""
    ke0 = float(one[0]["kinetic_energy"])
    mass = count * density * math.pi / 6 * diameter ** 3
    v_scale = math.sqrt(2 * ke0 / mass)
    scale = column_scales(one)
    for a in "xyz":
        scale[f"momentum_{a}"] = math.sqrt(2 * mass * ke0)
        scale[f"mean_v{a}"] = v_scale
        scale[f"mean_a{a}"] = v_scale / interval
    for c in ("overlap_mean", "overlap_max", "wall_overlap_mean", "wall_overlap_max"):
        scale[c] = scale["mean_x"] / diameter
    return scale


def axial_scales(one, kinds=("momentum_", "gas_momentum_")):
    """column_scales, where the x and z components of each vector in `kinds` take at least the
    axial (y) component's scale (a riser's lateral sums are round-off of the axial flow)."""
    scale = column_scales(one)
    for kind in kinds:
        for a in "xz":
            scale[kind + a] = max(scale[kind + a], scale[kind + "y"])
    return scale


def compare_rows(one, many, scale, tol, exact=(), skip=(), at_least=(), loose=(), label=""):
    """Every column of the R-rank rows `many` against the one-rank rows `one`, row by row:
    `skip` columns not at all, `exact` ones equal, `at_least` ones no smaller, `loose` ones within
    1e-12 relative, the others within `tol` of their scale (absolutely where the scale is 0).
    Returns the worst scaled difference per compared column (empty where none)."""
    assert len(one) == len(many), f"{label}: {len(one)} rows (1 rank) against {len(many)}"
    worst = {}
    where = f"{label}: " if label else ""
    for r1, rn in zip(one, many):
        for c in r1:
            if c in skip:
                continue
            x, y = float(r1[c]), float(rn[c])
            if c in loose:
                assert abs(x - y) <= 1e-12 * abs(x), f"{where}{c}: {x} vs {y}"
            elif c in exact:
                assert x == y, f"{where}{c}: {x} (1 rank) != {y} at t = {r1['time']}"
            elif c in at_least:
                assert y >= x, f"{where}{c}: {x} (1 rank) > {y} at t = {r1['time']}"
            else:
                err = abs(x - y) / scale[c] if scale[c] > 0 else abs(x - y)
                worst[c] = max(worst.get(c, 0.0), err)
                assert err <= tol, \
                    f"{where}{c}: {x} vs {y} at t = {r1['time']} (scaled error {err:.3g})"
    return worst


def worst_of(worst):
    """'3.1e-13 (kinetic_energy)': the largest scaled difference and its column."""
    if not worst:
        return "0 (no column compared)"
    c = max(worst, key=worst.get)
    return f"{worst[c]:.3g} ({c})"
