#include "dem/orb_local_rows.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include "dem/cell_list.hpp"

namespace cfddem::dem {

void OrbLocalRows::build(const Input& in) {
  const std::size_t owned = in.owned;
  const std::size_t n = in.x.size();
  const double prox = in.prox;
  // Cell list over the local store: the whole domain in cells of at least the cutoff, at most
  // about 8 per local particle (OrbScheme's rule), binned at wrapped positions.
  cells_.bin<true>(in.geom, make_cell_grid(in.geom, in.cutoff, n, 8.0), in.x.data(), in.y.data(),
                   in.z.data(), n);
  cell_has_owned_.assign(cells_.grid().count(), 0);
  for (std::size_t i = 0; i < owned; ++i)
    cell_has_owned_[cells_.cell_of()[i]] = 1;
  // Rows: own-leaf partners, then the others, each by id (OrbScheme's summation order); the
  // proximity flag of each owned particle, exact (OrbScheme's tests, the same expressions).
  off_.assign(owned + 1, 0);
  mid_.assign(owned, 0);
  nb_.clear();
  near_.assign(owned, 0);
  prox_.clear();
  const bool keep_prox = in.proximity_pairs && !in.ttc;
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
  const std::uint32_t* items = cells_.items().data();
  const std::uint32_t n_own = static_cast<std::uint32_t>(owned);
  if (cells_.grid().half_stencil()) {
    half_stencil(in);
  } else {
    // Fewer than three cells on an axis (a small box): each owned particle against the full
    // stencil, periodic images collapsed.
    for (std::size_t i = 0; i < owned; ++i) {
      own.clear(), other.clear();
      const double xi = px[i], yi = py[i], zi = pz[i], ri = pr[i], si = ttc ? sp[i] : 0.0;
      const std::uint32_t li = leaf[i];
      bool near = false;
      cells_.for_each_around(cells_.coord<true>(xi, 0), cells_.coord<true>(yi, 1),
                             cells_.coord<true>(zi, 2), [&](std::uint32_t s) {
                               const std::uint32_t j = items[s];
                               if (j == i)
                                 return;
                               const double dx = g.image(px[j] - xi, 0),
                                            dy = g.image(py[j] - yi, 1),
                                            dz = g.image(pz[j] - zi, 2);
                               const double r2 = dx * dx + dy * dy + dz * dz;
                               const double rs = ri + pr[j];
                               if (r2 < (rs + skin) * (rs + skin))
                                 (j < n_own && leaf[j] == li ? own : other).push_back(j);
                               const double pr_s = prox * rs + skin;
                               if (keep_prox && (j >= n_own || j > i) && r2 < pr_s * pr_s)
                                 prox_.push_back(static_cast<std::uint32_t>(i)),
                                     prox_.push_back(j);
                               near = near || (ttc ? within_reach(r2, rs, si + sp[j], dt_sp)
                                                   : within_proximity(r2, rs, prox));
                             });
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

void OrbLocalRows::proximity_flags(const DomainGeometry& g, std::span<const double> x,
                                   std::span<const double> y, std::span<const double> z,
                                   std::span<const double> radius, double prox) {
  std::fill(near_.begin(), near_.end(), 0);
  const std::size_t owned = near_.size();
  for (std::size_t q = 0; q < prox_.size(); q += 2) {
    const std::uint32_t a = prox_[q], b = prox_[q + 1];
    const double dx = g.image(x[b] - x[a], 0), dy = g.image(y[b] - y[a], 1),
                 dz = g.image(z[b] - z[a], 2);
    if (within_proximity(dx * dx + dy * dy + dz * dz, radius[a] + radius[b], prox)) {
      if (a < owned)
        near_[a] = 1;
      if (b < owned)
        near_[b] = 1;
    }
  }
}

// Rows and proximity flags from each pair of local particles once (not two ghosts): a cell and
// its 13 forward neighbours (OrbScheme::rebuild_pairs' half stencil, over copies in cell order),
// then the rows of the owned ends, each segment by id. The tests are those of the full stencil
// (symmetric in the pair), so the rows and flags are the same.
void OrbLocalRows::half_stencil(const Input& in) {
  const double prox = in.prox;
  const std::size_t owned = in.owned;
  const std::uint32_t n_own = static_cast<std::uint32_t>(owned);
  const DomainGeometry g = in.geom;
  const double skin = in.skin, dt_sp = in.dt_sp;
  const bool ttc = in.ttc;
  const bool keep_prox = in.proximity_pairs && !ttc;
  const std::uint32_t* items = cells_.items().data();
  const unsigned char* has_owned = cell_has_owned_.data();
  cells_.gather<5>({in.x.data(), in.y.data(), in.z.data(), in.radius.data(),
                    ttc ? in.speed.data() : in.radius.data()},
                   sorted_);
  const double* sx = sorted_[0].data();
  const double* sy = sorted_[1].data();
  const double* sz = sorted_[2].data();
  const double* sr = sorted_[3].data();
  const double* ss = sorted_[4].data();
  // Slabs of cells along z are TBB tasks, each with its own pair lists, joined in slab order
  // (the rows are sorted by id below, so neither the slabs nor the threads change a result).
  // A flag set from two slabs is set to the same value: an atomic store, no race.
  unsigned char* near = near_.data();
  const int nz = cells_.grid().n[2];
  const auto slabs = static_cast<std::size_t>(nz);
  if (slab_pairs_.size() < slabs)
    slab_pairs_.resize(slabs), slab_prox_.resize(slabs);
  auto slab = [&](int cz) {
    std::vector<std::uint32_t>& out = slab_pairs_[static_cast<std::size_t>(cz)];
    std::vector<std::uint32_t>& out_prox = slab_prox_[static_cast<std::size_t>(cz)];
    out.clear(), out_prox.clear();
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
      const double pr_s = prox * rs + skin;
      if (keep_prox && r2 < pr_s * pr_s)
        out_prox.push_back(i), out_prox.push_back(j);
      const bool close =
          ttc ? within_reach(r2, rs, ss[a] + ss[b], dt_sp) : within_proximity(r2, rs, prox);
      if (close) {
        if (i < n_own)
          std::atomic_ref<unsigned char>(near[i]).store(1, std::memory_order_relaxed);
        if (j < n_own)
          std::atomic_ref<unsigned char>(near[j]).store(1, std::memory_order_relaxed);
      }
    };
    // Cells of ghosts only meet only through cells holding owned particles.
    cells_.for_each_forward_pair(
        cz, [&](std::size_t c) { return has_owned[c] != 0; }, test);
  };
  tbb::parallel_for(
      tbb::blocked_range<int>(0, nz, 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int cz = r.begin(); cz != r.end(); ++cz)
          slab(cz);
      },
      tbb::simple_partitioner{});
  pair_a_.clear(), pair_b_.clear();
  for (std::size_t z = 0; z < slabs; ++z)
    for (std::size_t k = 0; k < slab_pairs_[z].size(); k += 2)
      pair_a_.push_back(slab_pairs_[z][k]), pair_b_.push_back(slab_pairs_[z][k + 1]);
  if (keep_prox)
    for (std::size_t z = 0; z < slabs; ++z)
      prox_.insert(prox_.end(), slab_prox_[z].begin(), slab_prox_[z].end());
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
