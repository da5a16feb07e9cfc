// Particle snapshots for ParaView / VisIt: one HDF5 file per snapshot (snapshot_<step>.h5, H5MD-like
// names under /particles) and one XDMF index (snapshots.xmf) over all of them, a temporal
// collection of Polyvertex grids with per-particle attributes (Center="Node"). Both are written
// under a temporary name and renamed, so a reader (ParaView polling a running job) never sees a
// torn file.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace cfddem {

struct SnapshotFields {
  double time = 0.0;
  std::int64_t step = 0;
  std::span<const double> x, y, z, vx, vy, vz, radius, mass;
  std::span<const std::int64_t> id;
  std::span<const std::int64_t> leaf; // ORB leaf / box of each particle; empty: none
  std::span<const double> local_dt;   // per particle; empty: `dt` for all
  double dt = 0.0;
};

// One entry of the index: what a snapshot file holds.
struct SnapshotEntry {
  std::int64_t step = 0;
  double time = 0.0;
  std::int64_t particles = 0;
  bool leaf = false;
  std::string file; // relative to the run directory
};

// Write <dir>/snapshot_<step>.h5 atomically; returns its index entry.
SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f);

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
