// Particles to the gas and forces back when the rank that owns a particle is not the one whose
// gas box holds it (the orb scheme's leaves are dealt to ranks by the knapsack, the gas grid is
// cut by its own ORB): once per fluid step, a copy of each owned particle goes to its gas box's
// rank, which deposits it and computes its force there (GasCoupling::step), and the force comes
// back to the owner in the owner's order. The box rule is the explicit scheme's
// (partition::decomposition_of_cell_boxes over the gas's boxes, wrapped centres), so for a
// scheme that already owns particles by gas box every copy stays home.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "dem/domain_geometry.hpp"
#include "partition/rank_decomposition.hpp"

namespace cfddem::apps {

class GasRouting {
public:
  // boxes: the gas boxes as a decomposition (one leaf group per rank, the same on every rank).
  GasRouting(const Communicator& comm, partition::RankDecomposition boxes,
             const dem::DomainGeometry& geom);

  // Collective. Sends a copy of each owned particle [0, owned) of `p` to the rank whose gas box
  // holds its wrapped centre; returns this rank's box store: the arrivals in id order (so the
  // deposit order depends on the particles only, not on threads, owners or their order). It
  // holds the wrapped x, y, z, the velocity (whatever the scheme
  // holds: the deposit and the force use the same v_i), radius, id and mass (with 1/m: the
  // drag time m / beta caps an adaptive fluid step and bounds a fixed one); the rest is left
  // zero (the gas coupling reads none of it).
  const ParticleStore& route(const ParticleStore& p, std::size_t owned);
  // Collective. f[a]: one value per particle of the box store, in its order (GasCoupling::force).
  // Sends each back to its owner; afterwards force(a) holds one value per owned particle of the
  // last route(), in the owner's order. Throws RunError if a returned id is not the one sent
  // (a routing bug: no particle may be lost or swapped).
  void return_force(const std::array<std::span<const double>, 3>& f);
  [[nodiscard]] std::span<const double> force(int axis) const { return force_[axis]; }

  // This rank: copies sent to other ranks in the last route(), and the wall time of all routes
  // and returns so far (packing, messages and unpacking).
  [[nodiscard]] std::size_t sent_away() const { return sent_away_; }
  [[nodiscard]] double seconds() const { return seconds_; }
  [[nodiscard]] const partition::RankDecomposition& boxes() const { return boxes_; }
  // The box store of the last route().
  [[nodiscard]] const ParticleStore& routed() const { return box_; }
  // New gas boxes (a gas regrid recut them): the next route() sends to their ranks.
  void set_boxes(partition::RankDecomposition boxes) { boxes_ = std::move(boxes); }

private:
  const Communicator& comm_;
  partition::RankDecomposition boxes_;
  dem::DomainGeometry geom_;
  ParticleStore box_; // the particles this rank's gas box deposits
  std::vector<std::int64_t> send_counts_, recv_counts_;
  std::vector<std::uint32_t> slot_;    // per owned particle: its place in the send order
  std::vector<std::int64_t> sent_id_;  // ids in the send order (checked on return)
  std::vector<std::uint32_t> arrival_; // per box store entry: its place in the arrivals
  std::vector<double> send_, recv_;
  std::array<std::vector<double>, 3> force_;
  std::size_t sent_away_ = 0;
  double seconds_ = 0.0;
};

} // namespace cfddem::apps
