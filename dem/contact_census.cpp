#include "dem/contact_census.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include "dem/cell_list.hpp"
#include "dem/contact_damping.hpp"
#include "dem/cylinder_wall.hpp"

namespace cfddem::dem {

namespace {

// Sums of the pair pass. Overlaps and rates are added in fixed point (units of 2^-32 of the
// diameter, and of the largest possible rate), so the sums do not depend on the order the pairs
// are met in: the census is the same whatever order the particles come in (ranks, schemes),
// without sorting them by id. A pair's own values do not depend on which particle is first
// (x_j - x_i = -(x_i - x_j) exactly).
constexpr double kFixed = 4294967296.0; // 2^32

struct Sums {
  std::int64_t contacts = 0, overlap = 0, rate = 0;
  double overlap_max = 0.0;
};

// 1 / t_c of the linear spring-dashpot for reduced mass m_eff, in units of `unit` (the rate of
// the lightest pair), cached for the last mass (equal masses: computed once).
struct RateCache {
  double k, e, unit, last_meff = -1.0;
  std::int64_t last = 0;
  std::int64_t operator()(double meff) {
    if (meff != last_meff) {
      last_meff = meff;
      last = unit > 0.0 ? std::llround(kFixed / contact_duration(k, e, meff) / unit) : 0;
    }
    return last;
  }
};

// The minimum image of the box held in locals for the pair loop (DomainGeometry::image, with the
// box's numbers in registers rather than re-read through a reference at every pair).
struct Image {
  double length[3], half[3];
  explicit Image(const DomainGeometry& g) {
    for (int a = 0; a < 3; ++a) {
      // A wall axis never shifts: half = infinity.
      length[a] = g.length[a];
      half[a] = g.periodic[a] ? g.half[a] : std::numeric_limits<double>::infinity();
    }
  }
  double operator()(double dx, int a) const {
    const double shift = static_cast<double>(dx > half[a]) - static_cast<double>(dx < -half[a]);
    return dx - shift * length[a];
  }
};

} // namespace

ContactCensus take_census(const CensusParticles& p, const DomainGeometry& g, const CensusLaws& l) {
  CensusWorkspace work;
  return take_census(p, g, l, work);
}

ContactCensus take_census(const CensusParticles& p, const DomainGeometry& g, const CensusLaws& l,
                          CensusWorkspace& s) {
  ContactCensus c;
  const std::size_t n = p.x.size();
  c.particles = static_cast<std::int64_t>(n);
  if (n == 0)
    return c;
  double r_max = 0.0, m_min = p.mass[0];
  for (std::size_t k = 0; k < n; ++k)
    r_max = std::max(r_max, p.radius[k]), m_min = std::min(m_min, p.mass[k]);

  // The shared cell list (dem/cell_list.hpp), cells at least the largest contact distance 2 r_max
  // wide and not many more than 4 per particle; the particles' values copied in slot order, the
  // positions wrapped into the box.
  const CellGrid grid = make_cell_grid(g, 2.0 * r_max, n, 4.0);
  s.cells.bin<true>(g, grid, p.x.data(), p.y.data(), p.z.data(), n);
  s.cells.gather<5>({p.x.data(), p.y.data(), p.z.data(), p.radius.data(), p.mass.data()}, s.slot);
  for (int a = 0; a < 3; ++a)
    for (double& v : s.slot[static_cast<std::size_t>(a)])
      v = g.wrap(v, a);
  s.z.assign(n, 0);

  const double pair_unit =
      m_min > 0.0 && l.k_pair > 0.0 ? 1.0 / contact_duration(l.k_pair, l.e_pair, 0.5 * m_min) : 0.0;
  RateCache pair_rate{l.k_pair, l.e_pair, pair_unit};
  Sums sums;
  const Image image(g);
  const double *px = s.slot[0].data(), *py = s.slot[1].data(), *pz = s.slot[2].data(),
               *pr = s.slot[3].data(), *pm = s.slot[4].data();
  // Slots a and b, in either order: a pair's values are the same both ways (x_j - x_i =
  // -(x_i - x_j) exactly), and the sums are order-free.
  const auto pair = [&](std::uint32_t a, std::uint32_t b) {
    const double dx = image(px[b] - px[a], 0), dy = image(py[b] - py[a], 1),
                 dz = image(pz[b] - pz[a], 2);
    const double reach = pr[a] + pr[b];
    const double d2 = dx * dx + dy * dy + dz * dz;
    if (d2 >= reach * reach)
      return;
    // A contact (rare): its overlap relative to the pair's mean diameter.
    const double overlap = (reach - std::sqrt(d2)) / reach;
    ++sums.contacts, ++s.z[a], ++s.z[b];
    sums.overlap += std::llround(overlap * kFixed);
    sums.overlap_max = std::max(sums.overlap_max, overlap);
    sums.rate += pair_rate(pm[a] * pm[b] / (pm[a] + pm[b]));
  };
  // Every pair once: a cell against itself and its 13 forward neighbours, or (fewer than 3 cells
  // on some axis, where a cell's neighbours coincide) each slot against the later slots of the
  // distinct cells around it.
  if (grid.half_stencil()) {
    for (int cz = 0; cz < grid.n[2]; ++cz)
      s.cells.for_each_forward_pair(
          cz, [](std::size_t) { return true; }, pair);
  } else {
    for (std::uint32_t a = 0; a < n; ++a) {
      // The slot's cell, from its wrapped position as the binning found it.
      const int cx = s.cells.coord<false>(px[a], 0), cy = s.cells.coord<false>(py[a], 1),
                cz = s.cells.coord<false>(pz[a], 2);
      s.cells.for_each_around(cx, cy, cz, [&](std::uint32_t b) {
        if (b > a)
          pair(a, b);
      });
    }
  }

  // Walls: the planes lo and hi of every non-periodic axis (dem/verlet_passes.hpp's walls); in
  // a cylindrical column its curved wall instead of the planes across it (docs/theory.md §11).
  const double wall_unit =
      m_min > 0.0 && l.k_wall > 0.0 ? 1.0 / contact_duration(l.k_wall, l.e_wall, m_min) : 0.0;
  RateCache wall_rate{l.k_wall, l.e_wall, wall_unit};
  Sums walls;
  // A wall at distance `gap` from the centre of particle i.
  auto wall = [&](std::size_t i, double gap) {
    const double ri = pr[i];
    if (ri - gap <= 0.0)
      return;
    const double overlap = (ri - gap) / (2.0 * ri);
    ++walls.contacts;
    walls.overlap += std::llround(overlap * kFixed);
    walls.overlap_max = std::max(walls.overlap_max, overlap);
    walls.rate += wall_rate(pm[i]);
  };
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a] || (g.cylinder && a != g.axis))
        continue;
      const double xa = s.slot[static_cast<std::size_t>(a)][i];
      for (const double gap : {xa - g.lo[a], g.hi[a] - xa})
        wall(i, gap);
    }
    if (g.cylinder)
      wall(i, cylinder_gap(g, s.slot[0][i], s.slot[1][i], s.slot[2][i], 0.0));
  }

  for (std::size_t i = 0; i < n; ++i)
    ++c.coordination[static_cast<std::size_t>(std::min(s.z[i], kCoordinationBins - 1))];
  const double inv_n = 1.0 / static_cast<double>(n);
  c.pair_contacts = sums.contacts, c.wall_contacts = walls.contacts;
  c.pair_overlap_max = sums.overlap_max, c.wall_overlap_max = walls.overlap_max;
  if (sums.contacts > 0)
    c.pair_overlap_mean =
        static_cast<double>(sums.overlap) / kFixed / static_cast<double>(sums.contacts);
  if (walls.contacts > 0)
    c.wall_overlap_mean =
        static_cast<double>(walls.overlap) / kFixed / static_cast<double>(walls.contacts);
  c.collision_frequency = 2.0 * static_cast<double>(sums.rate) / kFixed * pair_unit * inv_n;
  c.wall_collision_frequency = static_cast<double>(walls.rate) / kFixed * wall_unit * inv_n;
  return c;
}

} // namespace cfddem::dem
