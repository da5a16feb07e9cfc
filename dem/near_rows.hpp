// The dense mode's near rows on R ranks (dem/islands_ranks.cpp, step_together): the entries of
// the islands rows within r_i + r_j + s of each other, s the explicit scheme's skin, kept while
// no particle of the rank (owned or ghost) has moved s / 2 since they were taken.
//
// Why: the R-rank rows are built once per sub-iteration, wide enough for the whole sub-iteration
// (the skin at least 4 x the largest speed bound x dt_sp), and the dense mode steps every
// particle K times over them. In the 1e5 bed "auto" runs one sub-iteration per fluid step, K =
// 691, with a 211 um skin: every fine step evaluated about 56 row entries per particle, where
// the one-rank dense mode (the explicit scheme's passes, 25 um skin, rebuilt as particles move)
// evaluates about 3. Filtering the wide rows again whenever a particle has moved half the short
// skin gives the same contacts: a pair left out was at least r_i + r_j + s apart, so it cannot
// touch before one of its ends has moved s / 2 (Verlet 1967's skin argument). Left-out pairs add
// nothing to the forces (the contact law returns before touching the sums when apart, and with
// friction zeroes the spring of a pair apart, which the filter does for them), and the kept ones
// are summed in the rows' order: the forces are bit for bit those of the wide rows.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "dem/domain_geometry.hpp"
#include "dem/islands_kernels.hpp"

namespace cfddem::dem::islands {

struct NearRows {
  std::vector<std::uint32_t> off, nb;      // CSR over the wide rows' particles
  std::vector<std::uint32_t> from;         // each kept entry's index in the wide rows
  std::vector<double> x_ref, y_ref, z_ref; // every particle's position at the filter
  std::vector<double> hx, hy, hz;          // friction: the kept entries' springs
  double skin = 0.0;
  std::int64_t filters = 0;         // filters taken (a count for tests and reports)
  std::vector<unsigned char> moved; // near_rows_expired's flag per block (scratch)

  [[nodiscard]] Rows rows() const { return Rows{off, nb, {}}; }
};

namespace detail {
constexpr std::size_t kNearRowBlock = 1024; // rows per block of a filter pass
constexpr std::size_t kExpiryBlock = 4096;  // particles per block of the expiry test

inline std::size_t blocks_of(std::size_t n, std::size_t block) {
  return (n + block - 1) / block;
}

inline bool near(const Columns& c, const DomainGeometry& g, std::uint32_t i, std::uint32_t j,
                 double skin) {
  const double dx = g.image(c.x[j] - c.x[i], 0);
  const double dy = g.image(c.y[j] - c.y[i], 1);
  const double dz = g.image(c.z[j] - c.z[i], 2);
  const double reach = c.radius[i] + c.radius[j] + skin;
  return dx * dx + dy * dy + dz * dz < reach * reach;
}
} // namespace detail

// Filters rows [0, n_rows) of `wide` into `out` at the columns' present positions (minimum
// image), and records every particle's position (all `c.x.size()` of them). With friction
// (hx non-empty: the wide rows' springs) the kept entries' springs are copied into out.hx.. and
// the left-out ones zeroed in hx.. (a pair that far apart is not in contact). Blocks of rows
// through for_blocks (the caller's TaskBlocks runs them as tasks), each writing its own rows:
// the same result on any thread count.
template <class ForBlocks = SerialBlocks>
void filter_near_rows(const Rows& wide, std::size_t n_rows, const Columns& c,
                      const DomainGeometry& g, double skin, std::span<double> hx,
                      std::span<double> hy, std::span<double> hz, NearRows& out,
                      ForBlocks&& for_blocks = {}) {
  out.skin = skin;
  ++out.filters;
  out.off.assign(n_rows + 1, 0);
  const std::size_t nblocks = detail::blocks_of(n_rows, detail::kNearRowBlock);
  auto rows_of = [&](std::size_t b) {
    return std::array<std::size_t, 2>{b * detail::kNearRowBlock,
                                      std::min(n_rows, (b + 1) * detail::kNearRowBlock)};
  };
  for_blocks(nblocks, [&](std::size_t b) {
    const auto [i0, i1] = rows_of(b);
    for (std::size_t i = i0; i < i1; ++i) {
      std::uint32_t kept = 0;
      for (std::uint32_t k = wide.off[i]; k < wide.off[i + 1]; ++k)
        kept += detail::near(c, g, static_cast<std::uint32_t>(i), wide.nb[k], skin);
      out.off[i + 1] = kept;
    }
  });
  for (std::size_t i = 0; i < n_rows; ++i)
    out.off[i + 1] += out.off[i];
  const std::size_t total = out.off[n_rows];
  out.nb.resize(total);
  out.from.resize(total);
  const bool friction = !hx.empty();
  if (friction)
    out.hx.resize(total), out.hy.resize(total), out.hz.resize(total);
  for_blocks(nblocks, [&](std::size_t b) {
    const auto [i0, i1] = rows_of(b);
    for (std::size_t i = i0; i < i1; ++i) {
      std::uint32_t at = out.off[i];
      for (std::uint32_t k = wide.off[i]; k < wide.off[i + 1]; ++k) {
        const std::uint32_t j = wide.nb[k];
        if (detail::near(c, g, static_cast<std::uint32_t>(i), j, skin)) {
          out.nb[at] = j, out.from[at] = k;
          if (friction)
            out.hx[at] = hx[k], out.hy[at] = hy[k], out.hz[at] = hz[k];
          ++at;
        } else if (friction) {
          hx[k] = hy[k] = hz[k] = 0.0;
        }
      }
    }
  });
  const std::size_t n = c.x.size();
  out.x_ref.assign(c.x.begin(), c.x.begin() + static_cast<std::ptrdiff_t>(n));
  out.y_ref.assign(c.y.begin(), c.y.begin() + static_cast<std::ptrdiff_t>(n));
  out.z_ref.assign(c.z.begin(), c.z.begin() + static_cast<std::ptrdiff_t>(n));
}

// With friction: the kept entries' springs back into the wide rows' (before a new filter, and at
// the end of the steps).
inline void return_near_springs(const NearRows& near, std::span<double> hx, std::span<double> hy,
                                std::span<double> hz) {
  for (std::size_t a = 0; a < near.from.size(); ++a) {
    const std::uint32_t k = near.from[a];
    hx[k] = near.hx[a], hy[k] = near.hy[a], hz[k] = near.hz[a];
  }
}

// Whether some particle (owned or ghost) has moved more than 0.45 s since the filter (0.45, not
// 0.5: a margin for the rounding of the separations, which the filter and the contact law
// compute with the minimum image). A periodic wrap counts as a long move (a new filter).
// Blocks of particles through for_blocks, a flag each.
template <class ForBlocks = SerialBlocks>
bool near_rows_expired(NearRows& near, const Columns& c, ForBlocks&& for_blocks = {}) {
  const double limit = 0.45 * near.skin;
  const double l2 = limit * limit;
  const std::size_t n = near.x_ref.size();
  near.moved.assign(detail::blocks_of(n, detail::kExpiryBlock), 0);
  for_blocks(near.moved.size(), [&](std::size_t b) {
    const std::size_t i1 = std::min(n, (b + 1) * detail::kExpiryBlock);
    bool moved = false;
    for (std::size_t i = b * detail::kExpiryBlock; i < i1 && !moved; ++i) {
      const double dx = c.x[i] - near.x_ref[i], dy = c.y[i] - near.y_ref[i],
                   dz = c.z[i] - near.z_ref[i];
      moved = dx * dx + dy * dy + dz * dz > l2;
    }
    near.moved[b] = moved ? 1 : 0;
  });
  return std::find(near.moved.begin(), near.moved.end(), 1) != near.moved.end();
}

} // namespace cfddem::dem::islands
