// The gas solver's fields in a checkpoint as whole-grid datasets, so that a checkpoint does not
// depend on how many ranks wrote it. Each field (face velocities, p', eps_g and its two earlier
// values) is one 3-D dataset of the whole grid's padded index space (fluid/grid_field.hpp:
// N + 1 + 2 g points per axis, faces and ghost layers included; z, y, x, x fastest), which on one
// rank is exactly the solver's array. On R ranks every rank writes the points it owns (its cells
// and low faces, plus the ghost layers and last face beyond the domain faces its box touches:
// the boxes' pieces tile the padded grid) as a hyperslab, and reads back its whole padded box:
// the ghosts of an internal face come from the neighbour's owned points, which is what the halo
// exchange had put there (every field is saved right after its ghosts were filled), and the
// ghosts beyond the domain are the very values the box that touched that face held.
//
// The fields carry their own checksum: a sum over the owned points of a hash of (field, point,
// value), which any cutting into boxes sums to the same number, so R ranks verify what they read
// with one reduction.
#pragma once

#include <array>
#include <cstdint>

#include "apps/coupled_step.hpp"
#include "core/cell_box.hpp"
#include "core/hdf5_file.hpp"

namespace cfddem::apps {

// Where one rank's gas box sits in the whole grid (one rank: the box is the grid).
struct GasBlock {
  std::array<int, 3> cells{}; // the whole grid's cells
  CellBox box;
};

// The checksum's partial sums: the point hashes' four 16-bit parts summed apart, so that they add
// over the ranks as integers without overflow (below 2^44 points); combine_checksum turns them
// into one number.
using GasChecksum = std::array<std::int64_t, 4>;
std::int64_t combine_checksum(const GasChecksum& sums);

// Writes /gas/{u,v,w,p,eps_g,eps_g_old[,eps_g_prev]} (the group must exist): collective over the
// ranks of a create_collective file, else the whole grid from one process. Returns this rank's
// partial sums.
GasChecksum write_gas_grids(h5::File& f, const GasCoupling::State& s, const GasBlock& b,
                            bool collective);
// Reads this block's padded box of each field into s.solver and s.eps_prev (empty when the
// file has no eps_g_prev) and adds the points it owns to `sums`. Throws RunError when the
// datasets are not of this grid.
void read_gas_grids(const h5::File& f, const GasBlock& b, GasCoupling::State& s, GasChecksum& sums);
// The whole grid's cells from the datasets' shape (a one-rank read); throws RunError if absent.
std::array<int, 3> gas_grid_cells(const h5::File& f);

} // namespace cfddem::apps
