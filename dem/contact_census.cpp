#include "dem/contact_census.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "dem/contact_damping.hpp"

namespace cfddem::dem {

namespace {

// The cells of the search: at least the largest contact distance 2 r_max wide on every axis (so a
// contact is between neighbouring cells), and not many more cells than particles (a dilute box
// of small particles would otherwise allocate a cell per particle volume).
struct CellGrid {
  std::array<int, 3> n{1, 1, 1};
  std::array<double, 3> inv_width{};

  CellGrid(const DomainGeometry& g, double reach, std::size_t particles) {
    const double volume = g.length[0] * g.length[1] * g.length[2];
    const double target = std::max(64.0, 2.0 * static_cast<double>(particles));
    const double h = std::max(reach, std::cbrt(volume / target));
    for (int a = 0; a < 3; ++a) {
      const double cells = h > 0.0 ? std::floor(g.length[a] / h) : 1.0;
      n[a] = static_cast<int>(std::clamp(cells, 1.0, 1024.0));
      inv_width[a] = static_cast<double>(n[a]) / g.length[a];
    }
  }
  int index(double x, int a, const DomainGeometry& g) const {
    // Clamped: a particle a hair outside a wall, or exactly at a periodic face's hi, stays in the
    // edge cell.
    const double c = std::floor((x - g.lo[a]) * inv_width[a]);
    return static_cast<int>(std::clamp(c, 0.0, static_cast<double>(n[a] - 1)));
  }
  // The distinct cells next to c along axis a (itself included), in increasing order of offset.
  int neighbours(int c, int a, bool periodic, int out[3]) const {
    int k = 0;
    for (int d = -1; d <= 1; ++d) {
      int m = c + d;
      if (periodic)
        m = (m + n[a]) % n[a];
      else if (m < 0 || m >= n[a])
        continue;
      if (std::find(out, out + k, m) == out + k)
        out[k++] = m;
    }
    return k;
  }
};

} // namespace

ContactCensus take_census(const CensusParticles& p, const DomainGeometry& g, const CensusLaws& l) {
  ContactCensus c;
  const std::size_t n = p.x.size();
  c.particles = static_cast<std::int64_t>(n);
  if (n == 0)
    return c;

  // The particles in id order, positions put back into the periodic box.
  std::vector<std::uint32_t> order(n);
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return p.id[a] < p.id[b]; });
  std::vector<double> pos[3];
  const std::span<const double> in[3] = {p.x, p.y, p.z};
  std::vector<double> r(n), m(n);
  double r_max = 0.0;
  for (int a = 0; a < 3; ++a) {
    pos[a].resize(n);
    for (std::size_t k = 0; k < n; ++k)
      pos[a][k] = g.wrap(in[a][order[k]], a);
  }
  for (std::size_t k = 0; k < n; ++k) {
    r[k] = p.radius[order[k]], m[k] = p.mass[order[k]];
    r_max = std::max(r_max, r[k]);
  }

  // Counting sort into cells, stable: each cell lists its particles in id order.
  const CellGrid grid(g, 2.0 * r_max, n);
  const std::size_t cells = static_cast<std::size_t>(grid.n[0]) * grid.n[1] * grid.n[2];
  std::vector<std::array<int, 3>> cell_of(n);
  std::vector<std::uint32_t> start(cells + 1, 0), members(n);
  const auto flat = [&](int i, int j, int k) {
    return (static_cast<std::size_t>(i) * grid.n[1] + j) * grid.n[2] + k;
  };
  for (std::size_t k = 0; k < n; ++k) {
    for (int a = 0; a < 3; ++a)
      cell_of[k][a] = grid.index(pos[a][k], a, g);
    ++start[flat(cell_of[k][0], cell_of[k][1], cell_of[k][2]) + 1];
  }
  std::partial_sum(start.begin(), start.end(), start.begin());
  {
    std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
    for (std::size_t k = 0; k < n; ++k)
      members[fill[flat(cell_of[k][0], cell_of[k][1], cell_of[k][2])]++] =
          static_cast<std::uint32_t>(k);
  }

  // Pairs: each once, from the particle earlier in id order.
  std::vector<int> z(n, 0);
  double overlap_sum = 0.0, rate = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    int nb[3][3], count[3];
    for (int a = 0; a < 3; ++a)
      count[a] = grid.neighbours(cell_of[i][a], a, g.periodic[a], nb[a]);
    for (int u = 0; u < count[0]; ++u)
      for (int v = 0; v < count[1]; ++v)
        for (int w = 0; w < count[2]; ++w) {
          const std::size_t cell = flat(nb[0][u], nb[1][v], nb[2][w]);
          for (std::uint32_t q = start[cell]; q < start[cell + 1]; ++q) {
            const std::size_t j = members[q];
            if (j <= i)
              continue;
            const double dx = g.image(pos[0][j] - pos[0][i], 0);
            const double dy = g.image(pos[1][j] - pos[1][i], 1);
            const double dz = g.image(pos[2][j] - pos[2][i], 2);
            const double reach = r[i] + r[j];
            const double d2 = dx * dx + dy * dy + dz * dz;
            if (d2 >= reach * reach)
              continue;
            const double overlap = (reach - std::sqrt(d2)) / reach;
            ++c.pair_contacts, ++z[i], ++z[j];
            overlap_sum += overlap;
            c.pair_overlap_max = std::max(c.pair_overlap_max, overlap);
            rate += 1.0 / contact_duration(l.k_pair, l.e_pair, m[i] * m[j] / (m[i] + m[j]));
          }
        }
  }
  // Walls: the planes lo and hi of every non-periodic axis (dem/verlet_passes.hpp's walls).
  double wall_overlap_sum = 0.0, wall_rate = 0.0;
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (const double gap : {pos[a][i] - g.lo[a], g.hi[a] - pos[a][i]}) {
        if (r[i] - gap <= 0.0)
          continue;
        const double overlap = (r[i] - gap) / (2.0 * r[i]);
        ++c.wall_contacts;
        wall_overlap_sum += overlap;
        c.wall_overlap_max = std::max(c.wall_overlap_max, overlap);
        wall_rate += 1.0 / contact_duration(l.k_wall, l.e_wall, m[i]);
      }
    }

  for (std::size_t i = 0; i < n; ++i)
    ++c.coordination[static_cast<std::size_t>(std::min(z[i], kCoordinationBins - 1))];
  const double inv_n = 1.0 / static_cast<double>(n);
  if (c.pair_contacts > 0)
    c.pair_overlap_mean = overlap_sum / static_cast<double>(c.pair_contacts);
  if (c.wall_contacts > 0)
    c.wall_overlap_mean = wall_overlap_sum / static_cast<double>(c.wall_contacts);
  c.collision_frequency = 2.0 * rate * inv_n;
  c.wall_collision_frequency = wall_rate * inv_n;
  return c;
}

} // namespace cfddem::dem
