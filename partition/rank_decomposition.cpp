#include "partition/rank_decomposition.hpp"

#include <algorithm>
#include <cstdint>

#include "core/communicator_mpi.hpp"
#include "partition/knapsack.hpp"
#include "partition/parallel_orb.hpp"
#include "partition/space_filling_curve.hpp"

namespace cfddem::partition {

RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                            std::span<const double> y, std::span<const double> z,
                            const Aabb& domain, int levels) {
  return decompose(comm, x, y, z, {}, domain, levels);
}

RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                            std::span<const double> y, std::span<const double> z,
                            std::span<const double> weights, const Aabb& domain, int levels) {
  OrbOptions opt;
  opt.levels = levels;
  return decompose(comm, x, y, z, weights, domain, opt);
}

RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                            std::span<const double> y, std::span<const double> z,
                            std::span<const double> weights, const Aabb& domain,
                            const OrbOptions& opt) {
  const int levels = opt.levels;
  std::vector<OrbCut> cuts;
  if (comm.size() == 1) {
    const OrbTree serial = OrbTree::build(x, y, z, weights, domain, opt);
    cuts.assign(serial.cuts().begin(), serial.cuts().end());
  } else {
    MpiWait w(comm); // the median search is a chain of allreduces: count it as MPI time
    cuts = parallel_orb_cuts(mpi_comm(comm), x, y, z, weights, domain, opt);
  }
  RankDecomposition d;
  d.tree = OrbTree::from_cuts(x, y, z, domain, levels, std::move(cuts));
  const auto leaves = d.tree.leaves();
  // Knapsack weights: the particles' weights per box over all ranks (without weights, the
  // particle count: the explicit scheme's measured cost, every particle takes every step).
  std::vector<double> weight(leaves.size());
  std::vector<std::array<double, 3>> centres(leaves.size());
  const auto order_of = d.tree.order();
  for (std::size_t l = 0; l < leaves.size(); ++l) {
    if (weights.empty()) {
      weight[l] = static_cast<double>(leaves[l].size());
    } else {
      for (std::uint32_t k = leaves[l].begin; k < leaves[l].end; ++k) weight[l] += weights[order_of[k]];
    }
    centres[l] = leaves[l].box.centre();
  }
  comm.sum(weight);
  const auto order = sfc_order(centres, domain, CurveKind::hilbert);
  const KnapsackAssignment k = knapsack_along_curve(weight, order, comm.size());
  d.owner = k.owner;
  d.load = k.load;
  d.imbalance = k.imbalance;
  return d;
}

} // namespace cfddem::partition
