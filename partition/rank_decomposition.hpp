// Which rank owns which part of the domain: the parallel ORB cuts the domain into 2^L boxes over
// the particles of every rank (the same tree on all ranks), the boxes are listed along a Hilbert
// curve over their centres, and the knapsack cuts that list into one contiguous chunk per rank,
// balancing the particles per box (AMReX's SFC + knapsack distribution maps). Past the levels the
// ranks cut together (parallel_orb.hpp) the knapsack deals whole subtrees of those levels, and
// each rank owns the leaves of the subtrees it cut. The particles themselves stay where they are
// (ParticleExchange moves them).
#pragma once

#include <array>
#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "partition/orb_tree.hpp"

namespace cfddem::partition {

struct RankDecomposition {
  OrbTree tree;             // leaves = boxes; locate() and the halo searches
  std::vector<int> owner;   // rank of each leaf
  std::vector<double> load; // per rank: particles in its boxes
  double imbalance = 1.0;   // max load / mean load

  // Rank owning the point (a point of the closed domain); -1 outside it.
  [[nodiscard]] int owner_of(double x, double y, double z) const {
    const int leaf = tree.locate(x, y, z);
    return leaf < 0 ? -1 : owner[static_cast<std::size_t>(leaf)];
  }
};

// Collective: every rank passes its own particle centres (all in the closed domain).
// Levels: 2^levels >= ranks keeps every rank busy; more levels let the knapsack balance finer.
[[nodiscard]] RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                                          std::span<const double> y, std::span<const double> z,
                                          const Aabb& domain, int levels);
// The same with a weight per particle (finite, >= 0; empty: each weighs 1) for both the ORB's
// medians and the knapsack (the orb scheme's measured cost: particles x local steps). Integer
// weights sum exactly, so the boxes are the serial ORB's for the same weights.
[[nodiscard]] RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                                          std::span<const double> y, std::span<const double> z,
                                          std::span<const double> weights, const Aabb& domain,
                                          int levels);
// The same with the ORB's options: with options.snap every cut lies on a face of that grid (the
// orb scheme with a gas: each leaf a whole number of fluid cells, as the serial OrbScheme's).
[[nodiscard]] RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                                          std::span<const double> y, std::span<const double> z,
                                          std::span<const double> weights, const Aabb& domain,
                                          const OrbOptions& options);

} // namespace cfddem::partition
