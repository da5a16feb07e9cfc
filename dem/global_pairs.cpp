#include "dem/global_pairs.hpp"

#include <cmath>
#include <limits>

#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

std::int64_t GlobalPairs::from_rows(std::span<const std::uint32_t> off,
                                    std::span<const std::uint32_t> nb, std::size_t owned,
                                    std::span<const std::int64_t> id) {
  a.clear(), b.clear();
  std::int64_t once = 0;
  for (std::uint32_t i = 0; i < owned; ++i)
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      if (j < owned && j <= i)
        continue;
      a.push_back(i), b.push_back(j);
      once += j < owned || id[i] < id[j];
    }
  return once;
}

// Until each particle has moved skin/2 (so a pair skin), a pair whose raw separation is at most
// half a periodic length less two skins on every periodic axis keeps its raw separation as the
// minimum image (DomainGeometry::image returns it unchanged, bit for bit): the head stream skips
// the image, the tail takes it.
void GlobalPairs::split(const ParticleStore& p, std::size_t owned,
                        const std::array<std::span<const double>, 3>& ref,
                        const DomainGeometry& g, double skin) {
  const double* x = p.x.data();
  const double* y = p.y.data();
  const double* z = p.z.data();
  double lim[3];
  for (int k = 0; k < 3; ++k)
    lim[k] = g.periodic[k] ? g.half[k] - 2.0 * skin : std::numeric_limits<double>::infinity();
  const auto raw = [&](std::size_t q) {
    const std::uint32_t i = a[q], j = b[q];
    return std::abs(x[j] - x[i]) <= lim[0] && std::abs(y[j] - y[i]) <= lim[1] &&
           std::abs(z[j] - z[i]) <= lim[2];
  };
  head_.build(a, b, raw, 2 * kPairBlock);
  tail_.build(a, b, [&](std::size_t q) { return !raw(q); }, 2 * kPairBlock);
  if (g.cylinder || !(g.periodic[0] && g.periodic[1] && g.periodic[2]))
    near_walls(p, owned, ref, g, skin, near_wall_);
  else
    near_wall_.clear();
  nh_ = nt_ = 0;
}

void GlobalPairs::clear_forces(ParticleStore& p) const {
  clear_contact_forces<false>(p, p.size(), std::span<const PairContacts>(head_blocks_).first(nh_),
                              std::span<const PairContacts>(tail_blocks_).first(nt_), near_wall_);
}

void GlobalPairs::pass(ParticleStore& p, const DomainGeometry& g, const StepModel& m, double hk,
                       StepReport& rep) {
  nh_ = pair_pass<false, false, true>(p, head_, HistoryColumns{}, g, m, hk, head_blocks_, rep);
  nt_ = pair_pass<false, true, true>(p, tail_, HistoryColumns{}, g, m, hk, tail_blocks_, rep);
  scatter_contacts<false>(p, p.size(), std::span<const PairContacts>(head_blocks_).first(nh_),
                          std::span<const PairContacts>(tail_blocks_).first(nt_));
}

} // namespace cfddem::dem
