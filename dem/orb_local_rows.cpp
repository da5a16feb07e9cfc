#include "dem/orb_local_rows.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include "dem/verlet_list.hpp"

namespace cfddem::dem {

void OrbLocalRows::build(const Input& in) {
  const std::size_t owned = in.owned;
  const std::size_t n = in.x.size();
  const double prox = in.prox;
  // Cell list over the local store: the whole domain in cells of at least the cutoff, at most
  // about 8 per local particle (OrbScheme's rule), binned at wrapped positions.
  std::array<int, 3> nc{};
  std::array<double, 3> inv{};
  double cell = in.cutoff;
  const double volume = in.geom.length[0] * in.geom.length[1] * in.geom.length[2];
  const double target = 8.0 * static_cast<double>(n) + 64.0;
  if (volume / (cell * cell * cell) > target)
    cell = std::cbrt(volume / target);
  for (int a = 0; a < 3; ++a) {
    nc[a] = std::max(1, static_cast<int>(std::floor(in.geom.length[a] / cell)));
    inv[a] = nc[a] / in.geom.length[a];
  }
  const std::size_t ncell = static_cast<std::size_t>(nc[0]) * nc[1] * nc[2];
  auto coord = [&](double v, int a) {
    return std::clamp(static_cast<int>((in.geom.wrap(v, a) - in.geom.lo[a]) * inv[a]), 0,
                      nc[a] - 1);
  };
  cc_.resize(n);
  cell_start_.assign(ncell + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    cc_[i] = {coord(in.x[i], 0), coord(in.y[i], 1), coord(in.z[i], 2)};
    ++cell_start_[(static_cast<std::size_t>(cc_[i][2]) * nc[1] + cc_[i][1]) * nc[0] + cc_[i][0] +
                  1];
  }
  for (std::size_t c = 0; c < ncell; ++c)
    cell_start_[c + 1] += cell_start_[c];
  cell_items_.resize(n);
  {
    std::vector<std::uint32_t> fill(cell_start_.begin(), cell_start_.end() - 1);
    cell_has_owned_.assign(ncell, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t c =
          (static_cast<std::size_t>(cc_[i][2]) * nc[1] + cc_[i][1]) * nc[0] + cc_[i][0];
      cell_items_[fill[c]++] = static_cast<std::uint32_t>(i);
      cell_has_owned_[c] |= i < owned;
    }
  }
  // Rows: own-leaf partners, then the others, each by id (OrbScheme's summation order); the
  // proximity flag of each owned particle, exact (OrbScheme's tests, the same expressions).
  off_.assign(owned + 1, 0);
  mid_.assign(owned, 0);
  nb_.clear();
  near_.assign(owned, 0);
  const double* px = in.x.data();
  const double* py = in.y.data();
  const double* pz = in.z.data();
  const double* pr = in.radius.data();
  const std::int64_t* id = in.id.data();
  std::vector<std::uint32_t>& own = scratch_own_;
  std::vector<std::uint32_t>& other = scratch_other_;
  // Locals, so that the stores into the rows do not make the compiler reload them.
  const DomainGeometry g = in.geom;
  const double skin = in.skin, dt_sp = in.dt_sp;
  const bool ttc = in.ttc;
  const double* sp = in.speed.data();
  const std::uint32_t* leaf = in.leaf.data();
  const std::uint32_t* items = cell_items_.data();
  const std::uint32_t* start = cell_start_.data();
  const std::uint32_t n_own = static_cast<std::uint32_t>(owned);
  if (nc[0] >= 3 && nc[1] >= 3 && nc[2] >= 3) {
    half_stencil(in, nc);
  } else {
    // Fewer than three cells on an axis (a small box): each owned particle against the full
    // stencil, periodic images collapsed.
    for (std::size_t i = 0; i < owned; ++i) {
      own.clear(), other.clear();
      int sx[3], sy[3], sz[3];
      const int mx = stencil_axis(cc_[i][0], nc[0], g.periodic[0], sx);
      const int my = stencil_axis(cc_[i][1], nc[1], g.periodic[1], sy);
      const int mz = stencil_axis(cc_[i][2], nc[2], g.periodic[2], sz);
      const double xi = px[i], yi = py[i], zi = pz[i], ri = pr[i], si = ttc ? sp[i] : 0.0;
      const std::uint32_t li = leaf[i];
      bool near = false;
      for (int c2 = 0; c2 < mz; ++c2)
        for (int c1 = 0; c1 < my; ++c1)
          for (int c0 = 0; c0 < mx; ++c0) {
            const std::size_t q =
                (static_cast<std::size_t>(sz[c2]) * nc[1] + sy[c1]) * nc[0] + sx[c0];
            for (std::uint32_t s = start[q]; s < start[q + 1]; ++s) {
              const std::uint32_t j = items[s];
              if (j == i)
                continue;
              const double dx = g.image(px[j] - xi, 0), dy = g.image(py[j] - yi, 1),
                           dz = g.image(pz[j] - zi, 2);
              const double r2 = dx * dx + dy * dy + dz * dz;
              const double rs = ri + pr[j];
              if (r2 < (rs + skin) * (rs + skin))
                (j < n_own && leaf[j] == li ? own : other).push_back(j);
              near = near || (ttc ? within_reach(r2, rs, si + sp[j], dt_sp)
                                  : within_proximity(r2, rs, prox));
            }
          }
      sort_by_id(own.data(), own.data() + own.size(), id);
      sort_by_id(other.data(), other.data() + other.size(), id);
      off_[i] = static_cast<std::uint32_t>(nb_.size());
      nb_.insert(nb_.end(), own.begin(), own.end());
      mid_[i] = static_cast<std::uint32_t>(nb_.size());
      nb_.insert(nb_.end(), other.begin(), other.end());
      near_[i] = near;
    }
    off_[owned] = static_cast<std::uint32_t>(nb_.size());
  }
  // Only particles with a row get their contact force rewritten at each step.
  active_.clear();
  for (std::size_t i = 0; i < owned; ++i)
    if (off_[i + 1] > off_[i])
      active_.push_back(static_cast<std::uint32_t>(i));
}

// Rows and proximity flags from each pair of local particles once (not two ghosts): a cell and
// its 13 forward neighbours (OrbScheme::rebuild_pairs' half stencil, over copies in cell order),
// then the rows of the owned ends, each segment by id. The tests are those of the full stencil
// (symmetric in the pair), so the rows and flags are the same.
void OrbLocalRows::half_stencil(const Input& in, const std::array<int, 3>& nc) {
  const double prox = in.prox;
  const std::size_t owned = in.owned;
  const std::size_t n = in.x.size();
  const std::uint32_t n_own = static_cast<std::uint32_t>(owned);
  const DomainGeometry g = in.geom;
  const double skin = in.skin, dt_sp = in.dt_sp;
  const bool ttc = in.ttc;
  const std::uint32_t* items = cell_items_.data();
  const std::uint32_t* start = cell_start_.data();
  const unsigned char* has_owned = cell_has_owned_.data();
  for (auto& v : sorted_)
    v.resize(n);
  double* sx = sorted_[0].data();
  double* sy = sorted_[1].data();
  double* sz = sorted_[2].data();
  double* sr = sorted_[3].data();
  double* ss = sorted_[4].data();
  for (std::size_t k = 0; k < n; ++k) {
    const std::uint32_t i = items[k];
    sx[k] = in.x[i], sy[k] = in.y[i], sz[k] = in.z[i], sr[k] = in.radius[i];
    ss[k] = ttc ? in.speed[i] : 0.0;
  }
  // Slabs of cells along z are TBB tasks, each with its own pair lists, joined in slab order
  // (the rows are sorted by id below, so neither the slabs nor the threads change a result).
  // A flag set from two slabs is set to the same value: an atomic store, no race.
  unsigned char* near = near_.data();
  const auto slabs = static_cast<std::size_t>(nc[2]);
  if (slab_pairs_.size() < slabs)
    slab_pairs_.resize(slabs);
  static constexpr int kForward[13][3] = {
      {1, 0, 0},  {-1, 1, 0}, {0, 1, 0}, {1, 1, 0},  {-1, -1, 1}, {0, -1, 1}, {1, -1, 1},
      {-1, 0, 1}, {0, 0, 1},  {1, 0, 1}, {-1, 1, 1}, {0, 1, 1},   {1, 1, 1}};
  auto slab = [&](int cz) {
    std::vector<std::uint32_t>& out = slab_pairs_[static_cast<std::size_t>(cz)];
    out.clear();
    auto test = [&](std::uint32_t a, std::uint32_t b) {
      const std::uint32_t i = items[a], j = items[b];
      if (i >= n_own && j >= n_own)
        return; // two ghosts: neither row is this rank's
      const double dx = g.image(sx[b] - sx[a], 0), dy = g.image(sy[b] - sy[a], 1),
                   dz = g.image(sz[b] - sz[a], 2);
      const double r2 = dx * dx + dy * dy + dz * dz;
      const double rs = sr[a] + sr[b];
      if (r2 < (rs + skin) * (rs + skin))
        out.push_back(i), out.push_back(j);
      const bool close =
          ttc ? within_reach(r2, rs, ss[a] + ss[b], dt_sp) : within_proximity(r2, rs, prox);
      if (close) {
        if (i < n_own)
          std::atomic_ref<unsigned char>(near[i]).store(1, std::memory_order_relaxed);
        if (j < n_own)
          std::atomic_ref<unsigned char>(near[j]).store(1, std::memory_order_relaxed);
      }
    };
    for (int cy = 0; cy < nc[1]; ++cy)
      for (int cx = 0; cx < nc[0]; ++cx) {
        const std::size_t c = (static_cast<std::size_t>(cz) * nc[1] + cy) * nc[0] + cx;
        const std::uint32_t c0 = start[c], c1 = start[c + 1];
        if (c0 == c1)
          continue;
        const bool mine = has_owned[c] != 0; // cells of ghosts only meet only through owned cells
        if (mine)
          for (std::uint32_t a = c0; a < c1; ++a)
            for (std::uint32_t b = a + 1; b < c1; ++b)
              test(a, b);
        for (const auto& o : kForward) {
          int q[3] = {cx + o[0], cy + o[1], cz + o[2]};
          bool skip = false;
          for (int ax = 0; ax < 3; ++ax)
            if (q[ax] < 0 || q[ax] >= nc[ax]) {
              if (!g.periodic[ax])
                skip = true;
              q[ax] = (q[ax] + nc[ax]) % nc[ax];
            }
          if (skip)
            continue;
          const std::size_t d = (static_cast<std::size_t>(q[2]) * nc[1] + q[1]) * nc[0] + q[0];
          if (!mine && !has_owned[d])
            continue;
          for (std::uint32_t a = c0; a < c1; ++a)
            for (std::uint32_t b = start[d]; b < start[d + 1]; ++b)
              test(a, b);
        }
      }
  };
  tbb::parallel_for(
      tbb::blocked_range<int>(0, nc[2], 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int cz = r.begin(); cz != r.end(); ++cz)
          slab(cz);
      },
      tbb::simple_partitioner{});
  pair_a_.clear(), pair_b_.clear();
  for (std::size_t z = 0; z < slabs; ++z)
    for (std::size_t k = 0; k < slab_pairs_[z].size(); k += 2)
      pair_a_.push_back(slab_pairs_[z][k]), pair_b_.push_back(slab_pairs_[z][k + 1]);
  // Rows of the owned ends: own-leaf partners first, then the others.
  std::vector<std::uint32_t>& own_count = scratch_own_;
  own_count.assign(owned, 0);
  std::fill(off_.begin(), off_.end(), 0);
  const std::uint32_t* leaf = in.leaf.data();
  auto same_leaf = [&](std::uint32_t i, std::uint32_t j) {
    return i < n_own && j < n_own && leaf[i] == leaf[j];
  };
  for (std::size_t q = 0; q < pair_a_.size(); ++q) {
    const std::uint32_t i = pair_a_[q], j = pair_b_[q];
    const bool same = same_leaf(i, j);
    if (i < n_own)
      ++off_[i + 1], own_count[i] += same;
    if (j < n_own)
      ++off_[j + 1], own_count[j] += same;
  }
  for (std::size_t i = 0; i < owned; ++i)
    off_[i + 1] += off_[i];
  std::vector<std::uint32_t>& fill_own = scratch_other_;
  fill_own.resize(owned);
  fill_other_.resize(owned);
  for (std::size_t i = 0; i < owned; ++i) {
    mid_[i] = off_[i] + own_count[i];
    fill_own[i] = off_[i], fill_other_[i] = mid_[i];
  }
  nb_.resize(off_[owned]);
  for (std::size_t q = 0; q < pair_a_.size(); ++q) {
    const std::uint32_t i = pair_a_[q], j = pair_b_[q];
    const bool same = same_leaf(i, j);
    if (i < n_own)
      nb_[same ? fill_own[i]++ : fill_other_[i]++] = j;
    if (j < n_own)
      nb_[same ? fill_own[j]++ : fill_other_[j]++] = i;
  }
  const std::int64_t* id = in.id.data();
  for (std::size_t i = 0; i < owned; ++i) {
    sort_by_id(nb_.data() + off_[i], nb_.data() + mid_[i], id);
    sort_by_id(nb_.data() + mid_[i], nb_.data() + off_[i + 1], id);
  }
}

} // namespace cfddem::dem
