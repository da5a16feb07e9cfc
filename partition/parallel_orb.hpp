// ORB over points spread across MPI ranks, in two parts. The top levels (shared_orb_levels: a
// few subtrees per rank) are agreed collectively: every cut's weighted median is found with
// reductions (a 256-way search on the coordinate's bit pattern, one allreduce per 8 bits) and
// the cut made with the serial build's rules (orb_cut_rules.hpp). The subtrees below them are
// dealt to ranks by the Hilbert knapsack, each subtree's points are sent to its rank, and that
// rank cuts the levels below alone (orb_subtree_cuts); the cuts are then shared. A node's cut
// depends only on its box and its points, so the result is the serial tree of the union of the
// ranks' points: bit for bit with unit or integer weights, to the rounding of the weight sums
// otherwise. The reductions' bytes grow with the rank count, not with the levels (the
// particles): what grows with the levels is the shared cuts, 16 bytes per leaf.
#pragma once

#include <span>
#include <vector>

#include "core/communicator.hpp"
#include "partition/orb_tree.hpp"

namespace cfddem::partition {

// Levels cut collectively on `ranks` ranks: ceil(log2 ranks) + 3 (8 to 16 subtrees per rank, so
// the knapsack can balance them), at most `levels`.
[[nodiscard]] int shared_orb_levels(int ranks, int levels);

struct ParallelOrb {
  std::vector<OrbCut> cuts; // heap order, the serial tree's
  int shared_levels = 0;    // levels cut collectively
  // When shared_levels < levels: per subtree below them (heap order, 2^shared_levels), the rank
  // that cut it and its weight (the points' weights, or their count without weights). Every
  // leaf of a subtree is that rank's (rank_decomposition.cpp). Empty otherwise.
  std::vector<int> subtree_rank;
  std::vector<double> subtree_weight;
};

// Collective over `comm`: same domain and options on every rank; each rank passes its own points
// (weights empty = each weighs 1, or one per local point).
[[nodiscard]] ParallelOrb parallel_orb_cuts(const Communicator& comm, std::span<const double> x,
                                            std::span<const double> y, std::span<const double> z,
                                            std::span<const double> weights, const Aabb& domain,
                                            const OrbOptions& options);

} // namespace cfddem::partition
