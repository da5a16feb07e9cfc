// Snapshots for ParaView / VisIt: one HDF5 file per snapshot (snapshot_<step>.h5, H5MD-like
// names under /particles; with a gas, the cell data under /fluid) and one XDMF index
// (snapshots.xmf) over all of them: a temporal collection of Polyvertex grids with per-particle
// attributes (Center="Node") and, with a gas, a second temporal collection of rectilinear grids
// (3DRectMesh, node coordinates per axis) with cell-centred attributes (Center="Cell"). Both are
// written under a temporary name and renamed, so a reader (ParaView polling a running job) never
// sees a torn file.
#pragma once

#include <mpi.h>

#include "core/communicator.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace cfddem {

// The gas on its grid at the snapshot's time: nx x ny x nz cells between node coordinates
// x_nodes (nx + 1 values), ...; cell arrays in C order with x fastest, i.e. shape (nz, ny, nx),
// the order XDMF's 3DRectMesh dimensions are given in.
struct CellFields {
  std::array<std::int64_t, 3> cells{}; // nx, ny, nz
  // On several ranks, this rank's block of cells: [block_lo, block_lo + block_cells) per axis,
  // the arrays below holding only it (block_cells all zero: the whole grid).
  std::array<std::int64_t, 3> block_lo{}, block_cells{};
  std::vector<double> x_nodes, y_nodes, z_nodes;
  std::vector<double> eps_g;        // gas volume fraction
  std::vector<double> pressure;     // full pressure p' + gp0 . (x - lo) [Pa]
  std::vector<double> gas_velocity; // face velocities averaged to cell centres, 3 per cell
};

struct SnapshotFields {
  double time = 0.0;
  std::int64_t step = 0;
  std::span<const double> x, y, z, vx, vy, vz, radius, mass;
  std::span<const std::int64_t> id;
  std::span<const std::int64_t> leaf; // ORB leaf / box of each particle; empty: none
  std::span<const double> local_dt;   // per particle; empty: `dt` for all
  double dt = 0.0;
  const CellFields* cells = nullptr; // null: no gas
};

// One entry of the index: what a snapshot file holds.
struct SnapshotEntry {
  std::int64_t step = 0;
  double time = 0.0;
  std::int64_t particles = 0;
  bool leaf = false;
  std::array<std::int64_t, 3> cells{}; // the fluid grid's cells; zeros: no cell data
  std::string file; // relative to the run directory
};

// Write <dir>/snapshot_<step>.h5 atomically (particles, and cells if f.cells); returns its index
// entry.
SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f);

// The same from every rank of `comm` at once, each with its own particles (the fields' spans),
// written collectively into one file with parallel HDF5 (MPI-IO): the ranks' particles follow
// each other in rank order. Collective; the entry (all particles) is returned on every rank.
// With cell data every rank passes its block (CellFields::block_lo, block_cells), written into
// the whole grid's datasets; the node coordinates are the whole grid's on every rank.
SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f,
                                      MPI_Comm comm);
// The same over a Communicator (core/communicator.hpp); one rank: the serial writer.
SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f,
                                      const Communicator& comm);

// The XDMF text for a list of snapshots (exposed for tests).
std::string xdmf_index(const std::vector<SnapshotEntry>& entries);

class SnapshotIndex {
public:
  explicit SnapshotIndex(std::string dir) : dir_(std::move(dir)) {}
  // Append and rewrite <dir>/snapshots.xmf atomically.
  void add(const SnapshotEntry& e);
  // Entries kept from a checkpoint (restart); files missing in the run directory are dropped.
  void restore(const std::vector<SnapshotEntry>& entries);
  const std::vector<SnapshotEntry>& entries() const { return entries_; }

private:
  std::string dir_;
  std::vector<SnapshotEntry> entries_;
};

} // namespace cfddem
