#include "partition/rank_decomposition.hpp"

#include <algorithm>
#include <cstdint>

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
  RankDecomposition d;
  if (comm.size() == 1) {
    const OrbTree serial = OrbTree::build(x, y, z, weights, domain, opt);
    d.tree = OrbTree::from_cuts(x, y, z, domain, levels,
                                std::vector<OrbCut>(serial.cuts().begin(), serial.cuts().end()));
  } else {
    ParallelOrb orb = parallel_orb_cuts(comm, x, y, z, weights, domain, opt);
    d.tree = OrbTree::from_cuts(x, y, z, domain, levels, std::move(orb.cuts));
    if (!orb.leaf_rank.empty()) {
      // The subtrees were dealt to ranks already: each rank owns the leaves it cut (it holds
      // their points now).
      d.owner = std::move(orb.leaf_rank);
      d.load = std::move(orb.rank_load);
      double total = 0.0;
      for (const double q : d.load) total += q;
      const double mean = total / comm.size();
      d.imbalance = mean > 0.0 ? *std::max_element(d.load.begin(), d.load.end()) / mean : 1.0;
      return d;
    }
  }
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
