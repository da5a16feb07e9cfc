#include "dem/contact_census.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
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
    const double target = std::max(27.0, 4.0 * static_cast<double>(particles));
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
  std::size_t flat(int i, int j, int k) const {
    return (static_cast<std::size_t>(i) * n[1] + j) * n[2] + k;
  }
  // The distinct cells next to c along axis a (itself included).
  int neighbours(int c, int a, bool periodic, int out[3]) const {
    int k = 0;
    for (int d = -1; d <= 1; ++d) {
      int m = c + d;
      if (m < 0 || m >= n[a]) {
        if (!periodic)
          continue;
        m += m < 0 ? n[a] : -n[a];
      }
      if (std::find(out, out + k, m) == out + k)
        out[k++] = m;
    }
    return k;
  }
};

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

// Cell ranges [lo, hi] along the last axis around c (c - 1 .. c + 1), cut in two where a periodic
// axis wraps, or the whole axis when it has fewer than 3 cells; returns how many.
int z_ranges(int c, int cells, bool periodic, int lo[2], int hi[2]) {
  lo[0] = c - 1, hi[0] = c + 1;
  if (periodic && cells < 3) {
    lo[0] = 0, hi[0] = cells - 1;
    return 1;
  }
  if (periodic && lo[0] < 0) {
    lo[0] = 0, lo[1] = hi[1] = cells - 1;
    return 2;
  }
  if (periodic && hi[0] >= cells) {
    hi[0] = cells - 1, lo[1] = hi[1] = 0;
    return 2;
  }
  lo[0] = std::max(lo[0], 0), hi[0] = std::min(hi[0], cells - 1);
  return 1;
}

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

  // Counting sort into cells (each cell's particles in input order).
  const CellGrid grid(g, 2.0 * r_max, n);
  const std::size_t cells = static_cast<std::size_t>(grid.n[0]) * grid.n[1] * grid.n[2];
  const std::span<const double> in[3] = {p.x, p.y, p.z};
  for (int a = 0; a < 3; ++a)
    s.x[a].resize(n);
  s.r.resize(n), s.m.resize(n), s.cell.resize(n), s.coords.resize(n), s.cell_of.resize(n);
  s.z.assign(n, 0);
  s.start.assign(cells + 1, 0);
  for (std::size_t k = 0; k < n; ++k) {
    for (int a = 0; a < 3; ++a)
      s.coords[k][a] = grid.index(g.wrap(in[a][k], a), a, g);
    s.cell_of[k] =
        static_cast<std::uint32_t>(grid.flat(s.coords[k][0], s.coords[k][1], s.coords[k][2]));
    ++s.start[s.cell_of[k] + 1];
  }
  std::partial_sum(s.start.begin(), s.start.end(), s.start.begin());
  s.fill.assign(s.start.begin(), s.start.end() - 1);
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint32_t to = s.fill[s.cell_of[k]]++;
    for (int a = 0; a < 3; ++a)
      s.x[a][to] = g.wrap(in[a][k], a);
    s.r[to] = p.radius[k], s.m[to] = p.mass[k], s.cell[to] = s.coords[k];
  }
  const std::vector<std::uint32_t>& start = s.start;

  // Pairs, each once. The last axis runs fastest in the cell numbering, so the cells (j0, j1,
  // i2 - 1 .. i2 + 1) of a column are one contiguous range of particles (cut in two where a
  // periodic axis wraps). With at least 3 cells on every periodic axis, particle i meets the
  // later particles of its own cell, the next cell of its column and the 4 forward columns
  // (0, +1), (+1, -1), (+1, 0), (+1, +1): every pair once. With fewer, a cell's left and right
  // neighbours coincide: i then meets every distinct cell around it and takes the particles
  // after it in cell order.
  bool half = true;
  for (int a = 0; a < 3; ++a)
    half = half && (!g.periodic[a] || grid.n[a] >= 3);
  const double pair_unit =
      m_min > 0.0 && l.k_pair > 0.0 ? 1.0 / contact_duration(l.k_pair, l.e_pair, 0.5 * m_min) : 0.0;
  RateCache pair_rate{l.k_pair, l.e_pair, pair_unit};
  Sums sums;
  const Image image(g);
  const double *px = s.x[0].data(), *py = s.x[1].data(), *pz = s.x[2].data(), *pr = s.r.data();
  const auto range = [&](std::size_t i, int j0, int j1, int lo, int hi, std::uint32_t from) {
    const std::uint32_t e = start[grid.flat(j0, j1, hi) + 1];
    const double xi = px[i], yi = py[i], zi = pz[i], ri = pr[i];
    for (std::uint32_t j = std::max(start[grid.flat(j0, j1, lo)], from); j < e; ++j) {
      const double dx = image(px[j] - xi, 0), dy = image(py[j] - yi, 1), dz = image(pz[j] - zi, 2);
      const double reach = ri + pr[j];
      const double d2 = dx * dx + dy * dy + dz * dz;
      if (d2 >= reach * reach)
        continue;
      // A contact (rare): its overlap relative to the pair's mean diameter.
      const double overlap = (reach - std::sqrt(d2)) / reach;
      ++sums.contacts, ++s.z[i], ++s.z[j];
      sums.overlap += std::llround(overlap * kFixed);
      sums.overlap_max = std::max(sums.overlap_max, overlap);
      sums.rate += pair_rate(s.m[i] * s.m[j] / (s.m[i] + s.m[j]));
    }
  };
  for (std::size_t i = 0; i < n; ++i) {
    const int c0 = s.cell[i][0], c1 = s.cell[i][1], c2 = s.cell[i][2];
    int zlo[2], zhi[2];
    const int nz = z_ranges(c2, grid.n[2], g.periodic[2], zlo, zhi);
    const auto after_i = static_cast<std::uint32_t>(i + 1);
    if (half) {
      range(i, c0, c1, c2, c2, after_i);
      const int up = c2 + 1 < grid.n[2] ? c2 + 1 : (g.periodic[2] ? 0 : -1);
      if (up >= 0)
        range(i, c0, c1, up, up, 0);
      static constexpr int kForward[4][2] = {{0, 1}, {1, -1}, {1, 0}, {1, 1}};
      for (const auto& d : kForward) {
        int j[2] = {c0 + d[0], c1 + d[1]};
        bool inside = true;
        for (int a = 0; a < 2; ++a)
          if (j[a] < 0 || j[a] >= grid.n[a]) {
            inside = inside && g.periodic[a];
            j[a] += j[a] < 0 ? grid.n[a] : -grid.n[a];
          }
        if (!inside)
          continue;
        for (int w = 0; w < nz; ++w)
          range(i, j[0], j[1], zlo[w], zhi[w], 0);
      }
    } else {
      int cols[2][3];
      const int n0 = grid.neighbours(c0, 0, g.periodic[0], cols[0]);
      const int n1 = grid.neighbours(c1, 1, g.periodic[1], cols[1]);
      for (int u = 0; u < n0; ++u)
        for (int v = 0; v < n1; ++v)
          for (int w = 0; w < nz; ++w)
            range(i, cols[0][u], cols[1][v], zlo[w], zhi[w], after_i);
    }
  }

  // Walls: the planes lo and hi of every non-periodic axis (dem/verlet_passes.hpp's walls).
  const double wall_unit =
      m_min > 0.0 && l.k_wall > 0.0 ? 1.0 / contact_duration(l.k_wall, l.e_wall, m_min) : 0.0;
  RateCache wall_rate{l.k_wall, l.e_wall, wall_unit};
  Sums walls;
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (const double gap : {s.x[a][i] - g.lo[a], g.hi[a] - s.x[a][i]}) {
        if (s.r[i] - gap <= 0.0)
          continue;
        const double overlap = (s.r[i] - gap) / (2.0 * s.r[i]);
        ++walls.contacts;
        walls.overlap += std::llround(overlap * kFixed);
        walls.overlap_max = std::max(walls.overlap_max, overlap);
        walls.rate += wall_rate(s.m[i]);
      }
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
