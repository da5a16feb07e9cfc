// ORB over points spread across MPI ranks, the serial tree of the union of their points (bit for
// bit with unit or integer weights, to the rounding of the weight sums otherwise), built with
// messages that grow with the rank count, not with the levels (the particles):
//  - halvings: while a group of ranks is even and larger than `group_ranks`, it agrees on its
//    node's cut by reductions (a 256-way search on the coordinate's bit pattern, one allreduce
//    per 8 bits, and the serial build's rules, orb_cut_rules.hpp), and each rank swaps the other
//    side's points with its partner in the other half of the group (recursive coordinate
//    bisection's exchange, Berger & Bokhari 1987);
//  - a group's stage: the group agrees on the next shared_orb_levels(group size) levels the same
//    way, deals the subtrees below them to its ranks by the Hilbert knapsack over their weights,
//    sends each subtree's points to its rank, and that rank cuts the subtree alone
//    (orb_subtree_cuts): a node's cut depends only on its box and its points;
//  - every rank's cuts and subtrees are then all-gathered: 24 bytes per cut, the one part that
//    grows with the levels.
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
  int shared_levels = 0;    // the deepest level agreed by reductions (over all ranks or a group)
  // Unless every level was agreed by all ranks together: the rank that was dealt each leaf's
  // subtree (it holds the subtree's points now; rank_decomposition.cpp makes it the owner), and
  // per rank the weight of its subtrees (the points' weights, or their count without weights).
  // Empty in that case: decompose() deals the leaves.
  std::vector<int> leaf_rank;
  std::vector<double> rank_load;
};

// Collective over `comm`: same domain and options on every rank; each rank passes its own points
// (weights empty = each weighs 1, or one per local point). group_ranks: the largest group that
// takes the knapsack stage without halving first (more ranks per group balance snapped or uneven
// subtrees better; fewer cost fewer reductions).
[[nodiscard]] ParallelOrb parallel_orb_cuts(const Communicator& comm, std::span<const double> x,
                                            std::span<const double> y, std::span<const double> z,
                                            std::span<const double> weights, const Aabb& domain,
                                            const OrbOptions& options, int group_ranks = 8);

} // namespace cfddem::partition
