#include "partition/rank_decomposition.hpp"

#include <algorithm>

#include "core/communicator_mpi.hpp"
#include "partition/knapsack.hpp"
#include "partition/parallel_orb.hpp"
#include "partition/space_filling_curve.hpp"

namespace cfddem::partition {

RankDecomposition decompose(const Communicator& comm, std::span<const double> x,
                            std::span<const double> y, std::span<const double> z,
                            const Aabb& domain, int levels) {
  OrbOptions opt;
  opt.levels = levels;
  std::vector<OrbCut> cuts;
  if (comm.size() == 1) {
    const OrbTree serial = OrbTree::build(x, y, z, {}, domain, opt);
    cuts.assign(serial.cuts().begin(), serial.cuts().end());
  } else {
    MpiWait w(comm); // the median search is a chain of allreduces: count it as MPI time
    cuts = parallel_orb_cuts(mpi_comm(comm), x, y, z, {}, domain, opt);
  }
  RankDecomposition d;
  d.tree = OrbTree::from_cuts(x, y, z, domain, levels, std::move(cuts));
  const auto leaves = d.tree.leaves();
  // Knapsack weights: particles per box over all ranks (measured cost of the explicit scheme:
  // every particle takes every step).
  std::vector<double> weight(leaves.size());
  std::vector<std::array<double, 3>> centres(leaves.size());
  for (std::size_t l = 0; l < leaves.size(); ++l) {
    weight[l] = static_cast<double>(leaves[l].size());
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
