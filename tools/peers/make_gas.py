#!/usr/bin/python3
"""Make the initial state of a homogeneous cooling gas as a LAMMPS data file (atom_style sphere:
id type diameter density x y z, plus Velocities), the input both peer codes read and that
tools/lammps_data_to_csv.py turns into cfddem's particle CSV.

Positions: random sequential addition in batches inside a periodic cube of side L; a candidate is
dropped if it overlaps an accepted sphere or an earlier candidate of its own batch. Velocities:
N(0, sqrt(T0)) per component, net momentum removed, rescaled so (1/3)<|v - <v>|^2> = T0 exactly.
Same physical parameters (d = 100 um, rho = 1000 kg/m^3, T0 = 0.01 m^2/s^2) and the same sequence
of draws from numpy's default_rng(seed) as the peers' generator, so equal seeds give equal files.

usage: make_gas.py N L OUT.data SEED        (needs numpy + scipy: run with /usr/bin/python3)
  dilute 100k (phi 0.01): make_gas.py 100000 0.01736466  dilute100k.data 2
  dense 100k  (phi 0.30): make_gas.py 100000 0.005588464 dense100k.data  3
"""
import math
import sys

DIAMETER = 100e-6   # m
DENSITY = 1000.0    # kg/m^3
T0 = 1e-2           # m^2/s^2


def place(n, box, rng, diameter=DIAMETER):
    """Batch random sequential addition of n non-overlapping spheres in a periodic cube."""
    import numpy as np
    from scipy.spatial import cKDTree
    min_gap = diameter * 1.0000001
    accepted = np.empty((0, 3))
    while len(accepted) < n:
        missing = n - len(accepted)
        trial = rng.random((max(4 * missing, 1000), 3)) * box
        if len(accepted):
            nearest, _ = cKDTree(accepted, boxsize=box).query(trial, k=1)
            trial = trial[nearest > min_gap]
        # Within the batch, the lower index of each overlapping pair wins (scan pairs in order).
        clashes = cKDTree(trial, boxsize=box).query_pairs(min_gap, output_type='ndarray')
        ok = np.ones(len(trial), dtype=bool)
        if len(clashes):
            rejected = set()
            for a, b in sorted(map(tuple, clashes)):
                if a not in rejected:
                    rejected.add(b)
            ok[list(rejected)] = False
        accepted = np.vstack([accepted, trial[ok][:missing]])
    if len(cKDTree(accepted, boxsize=box).query_pairs(diameter)):
        raise RuntimeError("placement produced overlapping spheres")
    return accepted


def thermal_velocities(n, rng, temperature=T0):
    import numpy as np
    v = rng.normal(0.0, math.sqrt(temperature), (n, 3))
    v -= v.mean(axis=0)
    v *= math.sqrt(temperature / ((v ** 2).sum(axis=1).mean() / 3.0))
    return v


def write_data(path, pos, vel, box, seed):
    n = len(pos)
    phi = n * math.pi * DIAMETER ** 3 / 6 / box ** 3
    with open(path, 'w') as f:
        f.write(f"HCS N={n} L={box:.9e} phi={phi:.6f} T0={T0} seed={seed}\n\n")
        f.write(f"{n} atoms\n1 atom types\n\n")
        for lo_hi in ("x", "y", "z"):
            f.write(f"0 {box:.12e} {lo_hi}lo {lo_hi}hi\n")
        f.write("\nAtoms\n\n")
        for k, p in enumerate(pos, start=1):
            f.write(f"{k} 1 {DIAMETER:.9e} {DENSITY:.6f} {p[0]:.12e} {p[1]:.12e} {p[2]:.12e}\n")
        f.write("\nVelocities\n\n")
        for k, u in enumerate(vel, start=1):
            f.write(f"{k} {u[0]:.12e} {u[1]:.12e} {u[2]:.12e} 0 0 0\n")
    return phi


def make(n, box, path, seed):
    import numpy as np
    rng = np.random.default_rng(seed)
    pos = place(n, box, rng)
    vel = thermal_velocities(n, rng)
    phi = write_data(path, pos, vel, box, seed)
    return phi, (vel ** 2).sum(axis=1).mean() / 3


def main(argv):
    if len(argv) != 5:
        sys.exit(__doc__)
    n, box, path, seed = int(argv[1]), float(argv[2]), argv[3], int(argv[4])
    phi, temp = make(n, box, path, seed)
    print(f"wrote {path}: N={n} L={box:.6e} phi={phi:.6f} T={temp:.6e}")


if __name__ == "__main__":
    main(sys.argv)
