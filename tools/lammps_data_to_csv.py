#!/usr/bin/env python3
"""Convert a LAMMPS/LIGGGHTS data file (atom_style sphere: id type diameter density x y z, plus a
Velocities section) into cfddem's particle CSV (x,y,z,vx,vy,vz,diameter,density), so cfddem starts
from exactly the peers' initial state. Numbers are copied as text: no rounding.

usage: lammps_data_to_csv.py IN.data OUT.csv
"""
import sys


def convert(src, dst):
    atoms, vels, section = {}, {}, None
    with open(src) as f:
        for line in f:
            s = line.split('#')[0].strip()
            if not s:
                continue
            if s in ("Atoms", "Velocities") or s.startswith("Atoms"):
                section = "Velocities" if s.startswith("Velocities") else "Atoms"
                continue
            w = s.split()
            if section == "Atoms" and len(w) >= 7:
                atoms[int(w[0])] = (w[4], w[5], w[6], w[2], w[3])
            elif section == "Velocities" and len(w) >= 4:
                vels[int(w[0])] = (w[1], w[2], w[3])
    with open(dst, "w") as out:
        out.write("x,y,z,vx,vy,vz,diameter,density\n")
        for i in sorted(atoms):
            x, y, z, d, rho = atoms[i]
            vx, vy, vz = vels.get(i, ("0", "0", "0"))
            out.write(f"{x},{y},{z},{vx},{vy},{vz},{d},{rho}\n")
    return len(atoms)


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    n = convert(sys.argv[1], sys.argv[2])
    print(f"wrote {sys.argv[2]}: {n} particles")
