#!/usr/bin/env python3
"""Gas regrids of a coupled run on R ranks (partition.gas_regrid_interval) against 1 rank.

Usage: mpi_gas_regrid_test.py MPIEXEC CFDDEM SOURCE_DIR RANKS

The small periodic riser of mpi_coupled_test.py with every particle placed in its lower 40%: the
cell-count cut of the gas into boxes leaves the upper ranks idle. A regrid every 0.4 ms cuts
the boxes again by weight (cells + particle steps); the first one must move the boxes, lower the
predicted load imbalance (max/mean) below the count cut's, and move cells and particles to
their new owners. The physics is unchanged: every diagnostic column that does not depend on
when positions are wrapped or lists rebuilt (the means of the positions jump by L/N when a
particle is wrapped at the extra rebuild of a regrid; pair and build counters count lists)
agrees with the 1-rank run to 1e-9 of its scale, as without regrids, and no particle is lost.
"""
import os
import sys
import tempfile

from mpi_rows import axial_scales, compare_rows, run_rows, worst_of

MPIEXEC, CFDDEM, SOURCE, RANKS = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
SCENE = os.path.join(SOURCE, "scenes", "riser.toml")
CELLS = (12, 20, 12)
ARGS = ["domain.hi=[2.4e-3,4.0e-3,2.4e-3]", "particles.count=800", "particles.temperature=1e-4",
        "particles.region_hi=[2.4e-3,1.6e-3,2.4e-3]",
        f"fluid.cells=[{CELLS[0]},{CELLS[1]},{CELLS[2]}]", "run.end_time=2e-3",
        "output.interval=2e-4", "partition.gas_regrid_interval=4e-4", "--threads", "1", "--quiet"]
SKIP = ["wall_seconds", "gas_mass_residual", "mean_x", "mean_y", "mean_z", "force_evaluations",
        "neighbor_builds"]


def run(ranks, out):
    return run_rows(MPIEXEC, ranks, CFDDEM, SCENE, out, ARGS)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        one, _ = run(1, os.path.join(tmp, "np1"))
        many, info = run(RANKS, os.path.join(tmp, f"np{RANKS}"))
    regrids = info["gas_regrids"]
    assert len(regrids) == 4, regrids  # at 0.4, 0.8, 1.2, 1.6 ms
    first = regrids[0]
    assert first["moved"] and first["gas_values_sent"] > 0, first
    assert first["imbalance_after"] < first["imbalance_before"] - 0.1, first
    total = CELLS[0] * CELLS[1] * CELLS[2]
    assert sum(info["gas_cells_per_rank"]) == total, info["gas_cells_per_rank"]
    assert sum(info["owned_particles_at_end"]) == 800, info["owned_particles_at_end"]
    assert len(one) == len(many) == 11, (len(one), len(many))
    assert all(float(r["particles"]) == 800 for r in many), [r["particles"] for r in many]
    worst = worst_of(compare_rows(one, many, axial_scales(one), 1e-9, skip=SKIP))
    print(f"{RANKS} ranks: imbalance {first['imbalance_before']:.3f} -> "
          f"{first['imbalance_after']:.3f} at the first regrid, gas cells per rank "
          f"{info['gas_cells_per_rank']}; worst scaled column error {worst}")


if __name__ == "__main__":
    main()
