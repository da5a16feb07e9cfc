// ORB over points spread across MPI ranks: every cut's weighted median is found with reductions
// (a 256-way search on the coordinate's bit pattern: one allreduce per 8 bits), and the cut itself
// with the serial build's rules (orb_cut_rules.hpp), so all ranks agree on the tree and it is the
// serial tree of the union of their points: bit for bit with unit or integer weights, to the
// rounding of the weight sums otherwise.
#pragma once

#include <span>

#include <mpi.h>

#include "partition/orb_tree.hpp"

namespace cfddem::partition {

// Collective over `comm`: same domain and options on every rank; each rank passes its own points
// (weights empty = each weighs 1, or one per local point). Returns the cuts in heap order.
// Cost: 64 + a few allreduces per tree level, each of 2^level numbers.
std::vector<OrbCut> parallel_orb_cuts(MPI_Comm comm, std::span<const double> x,
                                      std::span<const double> y, std::span<const double> z,
                                      std::span<const double> weights, const Aabb& domain,
                                      const OrbOptions& options);

// The tree of those cuts over this rank's points (OrbTree::from_cuts).
OrbTree parallel_orb(MPI_Comm comm, std::span<const double> x, std::span<const double> y,
                     std::span<const double> z, std::span<const double> weights,
                     const Aabb& domain, const OrbOptions& options);

} // namespace cfddem::partition
