#include "dem/orb_scheme.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>
#include <stdexcept>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include "core/error.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

namespace {
enum class Fault { none = 0, nan, left_domain };

// Sort a short segment of partner indices by particle id (the canonical summation order: it
// survives every re-sort of the store, so a row's sum does not depend on the store's order).

void sort_by_id(std::uint32_t* first, std::uint32_t* last, const std::int64_t* id) {
  for (std::uint32_t* i = first + (first != last); i < last; ++i) {
    const std::uint32_t v = *i;
    std::uint32_t* j = i;
    for (; j > first && id[*(j - 1)] > id[v]; --j)
      *j = *(j - 1);
    *j = v;
  }
}
} // namespace

// A run of consecutive leaves with the same local step, advanced in lockstep as one TBB task:
// [b, e) in the store, rows active_[a0, a1). Leaves never read each other's live state (partners
// in other leaves are read from the frozen copies), so the grouping changes nothing in the
// arithmetic: it only amortises the per-step loop overhead of small leaves.
struct OrbScheme::Batch {
  std::uint32_t b = 0, e = 0, a0 = 0, a1 = 0;
  std::int64_t K = 1, evals_per_step = 0;
  double h = 0.0, h_last = 0.0;
  // Results of the last attempt.
  std::int64_t violations = 0;
  double max_ratio = 0.0;
  bool outran = false; // a particle moved more than skin/2 with force evaluations still to do
  Fault fault = Fault::none;
  std::uint32_t fault_index = 0;
  double fault_value = 0.0;
};

OrbScheme::~OrbScheme() = default;

OrbScheme::OrbScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain),
      model_(make_step_model(scene, particles)) {
  require_frictionless(model_, "orb");
  domain_ = partition::Aabb{scene.domain.lo, scene.domain.hi};
  for (std::size_t i = 0; i < p_.size(); ++i)
    r_max_ = std::max(r_max_, p_.radius[i]);
  if (p_.size() == 0)
    r_max_ = model_.r_min;
  nsubit_ = scene.dem.nsubit;
  dt_sp_ = scene.dem.regrid_interval / static_cast<double>(nsubit_);
  skin_ = model_.skin;
  cost_weights_ = scene.partition.weights == "cost";
  time_to_contact_ = scene.dem.local_dt == "time_to_contact";
  // The skin may grow (after a retry) while the contact cutoff stays below half of every
  // periodic length (minimum image).
  for (int a = 0; a < 3; ++a) // no particles: nothing to list (a gas-only or empty scene)
    if (p_.size() > 0 && geom_.periodic[a] && geom_.length[a] <= 2.0 * (2.0 * r_max_ + model_.skin))
      throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                                 "neighbor cutoff {:.4g} m",
                                 a, geom_.length[a], 2.0 * r_max_ + model_.skin));
  skin_cap_ = periodic_skin_cap(geom_, r_max_);
  hprev_.assign(p_.size(), 0.0);
  cost_.assign(p_.size(), 0.0);
}

void OrbScheme::start() {
  // v holds the synchronised v(0): the first kick is a(0) (0 + h/2), velocity Verlet's.
  hprev_.assign(p_.size(), 0.0);
  subits_ = 0;
}

// New index k holds old index order[k]: every per-particle array and the pair lists follow.
void OrbScheme::apply_permutation(std::span<const std::uint32_t> order) {
  const std::size_t n = order.size();
  p_.permute(order);
  auto permute = [&](std::vector<double>& v) {
    if (v.size() != n)
      return;
    std::vector<double>& t = dscratch_;
    t.resize(n);
    for (std::size_t k = 0; k < n; ++k)
      t[k] = v[order[k]];
    v.swap(t);
  };
  permute(hprev_), permute(cost_), permute(xr_), permute(yr_), permute(zr_);
  ext_.permute(order);
  scratch_.resize(n);
  for (std::size_t k = 0; k < n; ++k)
    scratch_[order[k]] = static_cast<std::uint32_t>(k);
  for (auto* v : {&ca_, &cb_, &pa_, &pb_})
    for (auto& i : *v)
      i = scratch_[i];
  off_.clear(); // rows must be derived again
}

void OrbScheme::regrid() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  // A skin grown by a retry lasts until the regrid: rows built with it stay valid (they hold
  // more pairs), and the next build uses the scene's skin again.
  skin_ = model_.skin;
  const std::size_t n = p_.size();
  // Wrap into the box; the reference positions move by the same period, so the displacement
  // since the last neighbor build is unchanged.
  for (std::size_t i = 0; i < n; ++i) {
    const double wx = geom_.wrap(p_.x[i], 0), wy = geom_.wrap(p_.y[i], 1),
                 wz = geom_.wrap(p_.z[i], 2);
    if (!xr_.empty())
      xr_[i] += wx - p_.x[i], yr_[i] += wy - p_.y[i], zr_[i] += wz - p_.z[i];
    p_.x[i] = wx, p_.y[i] = wy, p_.z[i] = wz;
  }
  bool use_cost = cost_weights_;
  if (use_cost) {
    double total = 0.0;
    for (double c : cost_)
      total += c;
    use_cost = total > 0.0; // the first regrid has no measurement yet: count
  }
  // With a gas, cuts lie on fluid cell faces (orb_snap_grid).
  tree_ = partition::OrbTree::build(
      p_.x, p_.y, p_.z, use_cost ? std::span<const double>(cost_) : std::span<const double>(),
      domain_, partition::OrbOptions{scene_.partition.orb_levels, orb_snap_grid(scene_)});
  const auto order = tree_.order();
  apply_permutation(order);
  std::fill(cost_.begin(), cost_.end(), 0.0);
  const auto leaves = tree_.leaves();
  ranges_.assign(leaves.size() + 1, 0);
  for (std::size_t l = 0; l < leaves.size(); ++l)
    ranges_[l + 1] = leaves[l].end;
  if (leaf_steps_.size() != leaves.size())
    leaf_steps_.assign(leaves.size(), 0);
  ++regrids_;
}

// Particles that left their leaf are moved to the leaf that now holds them, keeping every leaf a
// contiguous range. A few particles cross a boundary per sub-iteration, so instead of sorting the
// whole store each one walks along the leaves between its old and new leaf by swaps with the
// boundary slots (one swap per leaf passed); particles of other leaves keep their leaf. The
// order inside a leaf changes, which no result depends on (rows are summed in id order and the
// update is per particle). Then the pair lists are relabelled and the rows derived again.
void OrbScheme::resort() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  const std::size_t n = p_.size();
  const std::size_t nl = ranges_.size() - 1;
  std::vector<std::uint32_t>& target = leaf_of_; // the leaf holding each slot's particle
  target.resize(n);
  bool moved = false;
  const auto leaves = tree_.leaves();
  const double* __restrict xs = p_.x.data();
  const double* __restrict ys = p_.y.data();
  const double* __restrict zs = p_.z.data();
  for (std::size_t l = 0; l < nl; ++l) {
    const partition::Aabb box = leaves[l].box;
    const std::uint32_t b = ranges_[l], e = ranges_[l + 1];
    std::fill(target.begin() + b, target.begin() + e, static_cast<std::uint32_t>(l));
    // Most leaves keep all their particles: a branch-free pass (it vectorizes) finds them.
    std::uint64_t out = 0;
    for (std::uint32_t i = b; i < e; ++i)
      out |= sign_unless(box.lo[0] <= xs[i]) | sign_unless(xs[i] < box.hi[0]) |
             sign_unless(box.lo[1] <= ys[i]) | sign_unless(ys[i] < box.hi[1]) |
             sign_unless(box.lo[2] <= zs[i]) | sign_unless(zs[i] < box.hi[2]);
    if (!(out >> 63))
      continue;
    for (std::uint32_t i = b; i < e; ++i) {
      // Most particles are still inside their (half-open) box: skip the wrap and the tree
      // descent (a box lies inside the domain, so an unwrapped coordinate inside it is final).
      const double px = p_.x[i], py = p_.y[i], pz = p_.z[i];
      int k = static_cast<int>(l);
      if (!(box.lo[0] <= px && px < box.hi[0] && box.lo[1] <= py && py < box.hi[1] &&
            box.lo[2] <= pz && pz < box.hi[2]))
        k = tree_.locate(geom_.wrap(px, 0), geom_.wrap(py, 1), geom_.wrap(pz, 2));
      if (k < 0)
        throw RunError(fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left "
                                   "the domain",
                                   time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i]));
      target[i] = static_cast<std::uint32_t>(k);
      moved |= static_cast<std::size_t>(k) != l;
    }
  }
  if (!moved)
    return;
  std::vector<std::uint32_t>& origin = fill_; // original slot of the particle now in each slot
  origin.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    origin[i] = static_cast<std::uint32_t>(i);
  auto swap_slots = [&](std::uint32_t a, std::uint32_t c) {
    if (a == c)
      return;
    p_.swap(a, c);
    std::swap(hprev_[a], hprev_[c]);
    std::swap(cost_[a], cost_[c]);
    if (!xr_.empty())
      std::swap(xr_[a], xr_[c]), std::swap(yr_[a], yr_[c]), std::swap(zr_[a], zr_[c]);
    ext_.swap(a, c);
    std::swap(target[a], target[c]);
    std::swap(origin[a], origin[c]);
  };
  for (std::size_t l = 0; l < nl; ++l) {
    std::uint32_t i = ranges_[l];
    while (true) {
      i = std::max(i, ranges_[l]); // a particle walked out of the front of leaf l
      if (i >= ranges_[l + 1])
        break;
      const std::uint32_t dest = target[i];
      if (dest == l) {
        ++i;
        continue;
      }
      // Walk the particle at slot i to leaf dest; slot i then holds a particle of leaf l (the
      // boundary slot it was swapped with) and is checked again.
      std::uint32_t m = i;
      if (dest > l) {
        for (std::size_t j = l; j < dest; ++j) {
          const std::uint32_t last = ranges_[j + 1] - 1;
          swap_slots(m, last);
          m = last;
          --ranges_[j + 1];
        }
      } else {
        for (std::size_t j = l; j > dest; --j) {
          const std::uint32_t first = ranges_[j];
          swap_slots(m, first);
          m = first;
          ++ranges_[j];
        }
      }
    }
  }
  // Relabel the pair lists: old slot origin[k] is now slot k.
  scratch_.resize(n);
  for (std::size_t k = 0; k < n; ++k)
    scratch_[origin[k]] = static_cast<std::uint32_t>(k);
  for (auto* v : {&ca_, &cb_, &pa_, &pb_})
    for (auto& q : *v)
      q = scratch_[q];
  off_.clear(); // rows must be derived again
}

// True when some particle's displacement since the build plus its free flight over one
// sub-iteration exceeds skin/2: the rows are then rebuilt before the sub-iteration, in which the
// particle would likely outrun them. Positions and references are unwrapped alike (a regrid
// shifts both), so plain differences. (d + v dt)^2 <= 2 (d^2 + v^2 dt^2): the square roots are
// taken only for the few particles that fail that bound.
bool OrbScheme::rows_expire() const {
  const std::size_t n = p_.size();
  const double lim = 0.5 * skin_, lim2 = lim * lim, dt2 = dt_sp_ * dt_sp_;
  const double* x = p_.x.data();
  const double* y = p_.y.data();
  const double* z = p_.z.data();
  const double* vx = p_.vx.data();
  const double* vy = p_.vy.data();
  const double* vz = p_.vz.data();
  const double* xr = xr_.data();
  const double* yr = yr_.data();
  const double* zr = zr_.data();
  // Branch-free bound first (it vectorizes); the exact test only if the bound fails somewhere.
  std::uint64_t over = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double ex = x[i] - xr[i], ey = y[i] - yr[i], ez = z[i] - zr[i];
    const double d2 = ex * ex + ey * ey + ez * ez;
    const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
    over |= sign_unless(2.0 * (d2 + v2 * dt2) <= lim2);
  }
  if (!(over >> 63))
    return false;
  for (std::size_t i = 0; i < n; ++i) {
    const double ex = x[i] - xr[i], ey = y[i] - yr[i], ez = z[i] - zr[i];
    const double d2 = ex * ex + ey * ey + ez * ez;
    const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
    if (!(2.0 * (d2 + v2 * dt2) <= lim2) && !(std::sqrt(d2) + std::sqrt(v2) * dt_sp_ <= lim))
      return true; // NaN expires the rows too
  }
  return false;
}

// One cell list over the whole store (indices binned, the store is not moved): contact
// candidates within r_a + r_b + skin and proximity candidates within prox (r_a + r_b)/2 + skin,
// each pair once, in a deterministic order. Proximity candidates are skipped when every particle
// is within the proximity distance of every other (prox_all) or the proximity distance reaches
// half a periodic length (prox_brute: tested pair by pair at each sub-iteration instead).
void OrbScheme::rebuild_pairs() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  const std::size_t n = p_.size();
  const DomainGeometry& g = geom_;
  const double prox = 0.5 * scene_.dem.proximity_radii;
  const double contact_cut = 2.0 * r_max_ + skin_;
  const double prox_cut = 2.0 * prox * r_max_ + skin_;
  bool prox_cells = true;
  for (int a = 0; a < 3; ++a)
    if (g.periodic[a] && 2.0 * prox_cut >= g.length[a])
      prox_cells = false;
  const double cutoff = prox_cells ? std::max(contact_cut, prox_cut) : contact_cut;
  std::array<int, 3> nc{};
  std::array<double, 3> inv{};
  double cell = cutoff;
  const double volume = g.length[0] * g.length[1] * g.length[2];
  const double target = 8.0 * static_cast<double>(n) + 64.0;
  if (volume / (cell * cell * cell) > target)
    cell = std::cbrt(volume / target);
  for (int a = 0; a < 3; ++a) {
    nc[a] = std::max(1, static_cast<int>(std::floor(g.length[a] / cell)));
    inv[a] = nc[a] / g.length[a];
  }
  const std::size_t ncell = static_cast<std::size_t>(nc[0]) * nc[1] * nc[2];
  auto coord = [&](double v, int a) {
    return std::clamp(static_cast<int>((g.wrap(v, a) - g.lo[a]) * inv[a]), 0, nc[a] - 1);
  };
  cell_of_.resize(n);
  cell_start_.assign(ncell + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    cell_of_[i] = static_cast<std::uint32_t>(
        (static_cast<std::size_t>(coord(p_.z[i], 2)) * nc[1] + coord(p_.y[i], 1)) * nc[0] +
        coord(p_.x[i], 0));
    ++cell_start_[cell_of_[i] + 1];
  }
  for (std::size_t c = 0; c < ncell; ++c)
    cell_start_[c + 1] += cell_start_[c];
  scratch_.resize(n);
  {
    std::vector<std::uint32_t>& fill = fill_;
    fill.assign(cell_start_.begin(), cell_start_.end() - 1);
    for (std::size_t i = 0; i < n; ++i)
      scratch_[fill[cell_of_[i]]++] = static_cast<std::uint32_t>(i);
  }
  ca_.clear(), cb_.clear(), pa_.clear(), pb_.clear();
  const double* px = p_.x.data();
  const double* py = p_.y.data();
  const double* pz = p_.z.data();
  const double* pr = p_.radius.data();
  auto test = [&](std::uint32_t i, std::uint32_t j) {
    const double dx = g.image(px[j] - px[i], 0), dy = g.image(py[j] - py[i], 1),
                 dz = g.image(pz[j] - pz[i], 2);
    const double r2 = dx * dx + dy * dy + dz * dz;
    const double rs = pr[i] + pr[j];
    if (r2 < (rs + skin_) * (rs + skin_))
      ca_.push_back(i), cb_.push_back(j);
    if (prox_cells && r2 < (prox * rs + skin_) * (prox * rs + skin_))
      pa_.push_back(i), pb_.push_back(j);
  };
  if (nc[0] >= 3 && nc[1] >= 3 && nc[2] >= 3) {
    // Half stencil: each cell against itself (later entries) and its 13 forward neighbours,
    // so every pair is visited once and no cell twice. The binned particles' data are copied in
    // cell order so that the inner loops read contiguous memory.
    static constexpr int kFwd[13][3] = {{1, 0, 0},  {-1, 1, 0}, {0, 1, 0},  {1, 1, 0}, {-1, -1, 1},
                                        {0, -1, 1}, {1, -1, 1}, {-1, 0, 1}, {0, 0, 1}, {1, 0, 1},
                                        {-1, 1, 1}, {0, 1, 1},  {1, 1, 1}};
    // Interior cells reach their forward neighbours by constant offsets; cells on the grid's
    // faces wrap (periodic) or skip (wall) them.
    std::ptrdiff_t fwd_off[13];
    for (int o = 0; o < 13; ++o)
      fwd_off[o] =
          (static_cast<std::ptrdiff_t>(kFwd[o][2]) * nc[1] + kFwd[o][1]) * nc[0] + kFwd[o][0];
    // Cell c at (cx, cy, cz) on the grid's faces: its forward neighbour o, or kNoCell.
    auto boundary_forward_cell = [&](int cx, int cy, int cz, int o) -> std::uint32_t {
      int q[3] = {cx + kFwd[o][0], cy + kFwd[o][1], cz + kFwd[o][2]};
      for (int a = 0; a < 3; ++a)
        if (q[a] < 0 || q[a] >= nc[a]) {
          if (!g.periodic[a])
            return kNoCell;
          q[a] = (q[a] + nc[a]) % nc[a];
        }
      return static_cast<std::uint32_t>((static_cast<std::size_t>(q[2]) * nc[1] + q[1]) * nc[0] +
                                        q[0]);
    };
    std::vector<double>& sx = sorted_[0];
    std::vector<double>& sy = sorted_[1];
    std::vector<double>& sz = sorted_[2];
    std::vector<double>& sr = sorted_[3];
    sx.resize(n), sy.resize(n), sz.resize(n), sr.resize(n);
    for (std::size_t k = 0; k < n; ++k) {
      const std::uint32_t i = scratch_[k];
      sx[k] = px[i], sy[k] = py[i], sz[k] = pz[i], sr[k] = pr[i];
    }
    // Pair (a, b) of sorted slots: the test of `test` on the sorted copies.
    auto test_sorted = [&](std::uint32_t a, std::uint32_t b) {
      const double dx = g.image(sx[b] - sx[a], 0), dy = g.image(sy[b] - sy[a], 1),
                   dz = g.image(sz[b] - sz[a], 2);
      const double r2 = dx * dx + dy * dy + dz * dz;
      const double rs = sr[a] + sr[b];
      const double pc = prox * rs + skin_;
      if (r2 < (rs + skin_) * (rs + skin_))
        ca_.push_back(scratch_[a]), cb_.push_back(scratch_[b]);
      if (prox_cells && r2 < pc * pc)
        pa_.push_back(scratch_[a]), pb_.push_back(scratch_[b]);
    };
    for (int cz = 0; cz < nc[2]; ++cz)
      for (int cy = 0; cy < nc[1]; ++cy)
        for (int cx = 0; cx < nc[0]; ++cx) {
          const std::size_t c = (static_cast<std::size_t>(cz) * nc[1] + cy) * nc[0] + cx;
          const std::uint32_t c0 = cell_start_[c], c1 = cell_start_[c + 1];
          if (c0 == c1)
            continue;
          for (std::uint32_t a = c0; a < c1; ++a)
            for (std::uint32_t b = a + 1; b < c1; ++b)
              test_sorted(a, b);
          const bool interior =
              cx >= 1 && cx + 1 < nc[0] && cy >= 1 && cy + 1 < nc[1] && cz + 1 < nc[2];
          for (int o = 0; o < 13; ++o) {
            const std::uint32_t d =
                interior ? static_cast<std::uint32_t>(static_cast<std::ptrdiff_t>(c) + fwd_off[o])
                         : boundary_forward_cell(cx, cy, cz, o);
            if (d == kNoCell)
              continue;
            const std::uint32_t d0 = cell_start_[d], d1 = cell_start_[d + 1];
            for (std::uint32_t a = c0; a < c1; ++a)
              for (std::uint32_t b = d0; b < d1; ++b)
                test_sorted(a, b);
          }
        }
  } else {
    // Fewer than three cells on an axis: full stencil with periodic images collapsed, j > i.
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t c = cell_of_[i];
      const int cx = static_cast<int>(c % nc[0]), cy = static_cast<int>((c / nc[0]) % nc[1]),
                cz = static_cast<int>(c / (static_cast<std::size_t>(nc[0]) * nc[1]));
      int sx[3], sy[3], sz[3];
      const int mx = stencil_axis(cx, nc[0], g.periodic[0], sx);
      const int my = stencil_axis(cy, nc[1], g.periodic[1], sy);
      const int mz = stencil_axis(cz, nc[2], g.periodic[2], sz);
      for (int cc = 0; cc < mz; ++cc)
        for (int bb = 0; bb < my; ++bb)
          for (int aa = 0; aa < mx; ++aa) {
            const std::size_t q =
                (static_cast<std::size_t>(sz[cc]) * nc[1] + sy[bb]) * nc[0] + sx[aa];
            for (std::uint32_t k = cell_start_[q]; k < cell_start_[q + 1]; ++k)
              if (scratch_[k] > i)
                test(static_cast<std::uint32_t>(i), scratch_[k]);
          }
    }
  }
  prox_from_pairs_ = prox_cells;
  xr_ = p_.x, yr_ = p_.y, zr_ = p_.z;
  pairs_valid_ = true;
  off_.clear();
  ++builds_;
}

// Rows of the current leaves from the contact candidates (after a build or a re-sort).
void OrbScheme::derive_rows() {
  const std::size_t n = p_.size();
  const std::size_t nl = ranges_.size() - 1;
  leaf_of_.resize(n);
  for (std::size_t l = 0; l < nl; ++l)
    for (std::uint32_t i = ranges_[l]; i < ranges_[l + 1]; ++i)
      leaf_of_[i] = static_cast<std::uint32_t>(l);
  std::vector<std::uint32_t>& own = scratch_;
  own.assign(n, 0);
  off_.assign(n + 1, 0);
  for (std::size_t q = 0; q < ca_.size(); ++q) {
    const std::uint32_t a = ca_[q], b = cb_[q];
    ++off_[a + 1], ++off_[b + 1];
    if (leaf_of_[a] == leaf_of_[b])
      ++own[a], ++own[b];
  }
  for (std::size_t i = 0; i < n; ++i)
    off_[i + 1] += off_[i];
  mid_.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    mid_[i] = off_[i] + own[i];
  nb_.resize(off_[n]);
  std::vector<std::uint32_t>& fo = own; // fill cursors: own segment, then ghost segment
  std::vector<std::uint32_t>& fg = cell_of_;
  fg.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    fo[i] = off_[i], fg[i] = mid_[i];
  for (std::size_t q = 0; q < ca_.size(); ++q) {
    const std::uint32_t a = ca_[q], b = cb_[q];
    if (leaf_of_[a] == leaf_of_[b]) {
      nb_[fo[a]++] = b, nb_[fo[b]++] = a;
    } else {
      nb_[fg[a]++] = b, nb_[fg[b]++] = a;
    }
  }
  active_.clear();
  own_before_.resize(n + 1);
  own_before_[0] = 0;
  for (std::size_t i = 0; i < n; ++i)
    own_before_[i + 1] = own_before_[i] + (mid_[i] - off_[i]);
  for (std::size_t i = 0; i < n; ++i) {
    sort_by_id(nb_.data() + off_[i], nb_.data() + mid_[i], p_.id.data());
    sort_by_id(nb_.data() + mid_[i], nb_.data() + off_[i + 1], p_.id.data());
    if (off_[i + 1] > off_[i])
      active_.push_back(static_cast<std::uint32_t>(i));
  }
  // Only particles with a row get their contact force rewritten each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
}

// Each batch's rows (its range of active_) and force evaluations per local step (own-leaf
// entries count half a pair, other-leaf entries one: see pair_evaluations()).
void OrbScheme::bind_rows() {
  for (Batch& bt : batches_) {
    bt.a0 = static_cast<std::uint32_t>(std::lower_bound(active_.begin(), active_.end(), bt.b) -
                                       active_.begin());
    bt.a1 = static_cast<std::uint32_t>(std::lower_bound(active_.begin(), active_.end(), bt.e) -
                                       active_.begin());
    const std::int64_t own = static_cast<std::int64_t>(own_before_[bt.e] - own_before_[bt.b]);
    const std::int64_t all = static_cast<std::int64_t>(off_[bt.e] - off_[bt.b]);
    bt.evals_per_step = own / 2 + (all - own);
  }
}

void OrbScheme::run_batch(Batch& bt, bool record) {
  ext_.active() ? run_batch_impl<true>(bt, record) : run_batch_impl<false>(bt, record);
}

// With External, the per-particle external force is added to the contact force in every kick
// and in the synchronised velocity ((F + F_ext) / m + g, the explicit scheme's arithmetic).
template <bool External> void OrbScheme::run_batch_impl(Batch& bt, bool record) {
  bt.violations = 0;
  bt.max_ratio = 0.0;
  bt.outran = false;
  bt.fault = Fault::none;
  if (bt.e == bt.b)
    return;
  const DomainGeometry g = geom_;
  const StepModel m = model_;
  double* __restrict x = p_.x.data();
  double* __restrict y = p_.y.data();
  double* __restrict z = p_.z.data();
  double* __restrict vx = p_.vx.data();
  double* __restrict vy = p_.vy.data();
  double* __restrict vz = p_.vz.data();
  double* __restrict fx = p_.fx.data();
  double* __restrict fy = p_.fy.data();
  double* __restrict fz = p_.fz.data();
  double* __restrict hp = hprev_.data();
  const double* __restrict gx = gx_.data();
  const double* __restrict gy = gy_.data();
  const double* __restrict gz = gz_.data();
  const double* __restrict gvx = gvx_.data();
  const double* __restrict gvy = gvy_.data();
  const double* __restrict gvz = gvz_.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict mass = p_.mass.data();
  const double* __restrict im = p_.inv_mass.data();
  const double* __restrict fex = External ? ext_.x.data() : nullptr;
  const double* __restrict fey = External ? ext_.y.data() : nullptr;
  const double* __restrict fez = External ? ext_.z.data() : nullptr;
  const std::uint32_t* __restrict off = off_.data();
  const std::uint32_t* __restrict mid = mid_.data();
  const std::uint32_t* __restrict nb = nb_.data();
  const std::uint32_t* __restrict act = active_.data();
  const bool walls = !(g.periodic[0] && g.periodic[1] && g.periodic[2]);
  const double lim = m.max_overlap;
  const double half_skin2 = 0.25 * skin_ * skin_;
  const std::uint32_t b = bt.b, e = bt.e;
  double max_ratio = 0.0;
  std::int64_t violations = 0;
  double h_before = 0.0; // the previous local step (k > 0)
  const KickDriftColumns columns =
      kick_drift_columns(p_, xr_, yr_, zr_, External ? &ext_ : nullptr, hprev_);
  for (std::int64_t k = 0; k < bt.K; ++k) {
    const double hk = k + 1 == bt.K ? bt.h_last : bt.h;
    // Contact pass: the explicit scheme's pair arithmetic; partners of the own leaf read live,
    // partners of other leaves read frozen at the start of the sub-iteration.
    leaf_contact_pass(bt.a0, bt.a1, act, off, mid, nb, x, y, z, vx, vy, vz, gx, gy, gz, gvx, gvy,
                      gvz, rad, mass, fx, fy, fz, g, m, max_ratio, violations);
    if (walls)
      add_wall_forces(b, e, off, x, y, z, vx, vy, vz, rad, mass, fx, fy, fz, g, m.wall, lim,
                      max_ratio, violations);
    if (record && k == 0)
      synchronised_velocities<External>(b, e, vx, vy, vz, fx, fy, fz, fex, fey, fez, im, hp,
                                        m.gravity, svx_.data(), svy_.data(), svz_.data());
    // v(n+1/2) = v(n-1/2) + a(n) (h_prev + h/2), x(n+1) = x(n) + v(n+1/2) h (leaf_kick_drift).
    // Sign-bit AND instead of a max: vectorizes (see kick_drift_range.hpp).
    std::uint64_t still = ~std::uint64_t{0};
    leaf_kick_drift<External>(k, bt.K, columns.range(b, e), h_before, hk, m.gravity, half_skin2,
                              still);
    h_before = hk;
    // Ghosts do not move and were within skin/2 of their reference: own particles may use the
    // other half. Beyond it a pair could be missing from the rows: stop, the sub-iteration is
    // redone with a larger skin (NaN-safe: a NaN compares false here, fails below and is
    // reported as such).
    if (k + 1 < bt.K && !(still >> 63)) {
      bt.outran = true;
      break;
    }
  }
  bt.max_ratio = max_ratio;
  bt.violations = violations;
  // Faults are rare: a branch-free pass (it vectorizes) says whether to look for one. The sum
  // v2 + x + y + z is NaN or inf if any term is; a coordinate outside a wall's closed interval,
  // or NaN, fails the comparison (periodic axes get an infinite interval).
  {
    const WallBounds wb(g);
    const double(&lo)[3] = wb.lo;
    const double(&hi)[3] = wb.hi;
    const double inf = std::numeric_limits<double>::infinity();
    std::uint64_t bad = 0;
    for (std::uint32_t i = b; i < e; ++i) {
      const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
      const double t = v2 + x[i] + y[i] + z[i];
      bad |= sign_unless(t > -inf) | sign_unless(t < inf) | sign_unless(x[i] >= lo[0]) |
             sign_unless(x[i] <= hi[0]) | sign_unless(y[i] >= lo[1]) | sign_unless(y[i] <= hi[1]) |
             sign_unless(z[i] >= lo[2]) | sign_unless(z[i] <= hi[2]);
    }
    if (!(bad >> 63))
      return;
  }
  for (std::uint32_t i = b; i < e && bt.fault == Fault::none; ++i) {
    const double q[3] = {x[i], y[i], z[i]};
    const double v2 = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2])) {
      bt.fault = Fault::nan, bt.fault_index = i, bt.fault_value = v2;
      break;
    }
    for (int a = 0; a < 3; ++a)
      if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a])) {
        bt.fault = Fault::left_domain, bt.fault_index = i, bt.fault_value = q[a];
        break;
      }
  }
}

// One try at the sub-iteration with the current rows; false if some batch outran its rows.
bool OrbScheme::attempt(bool record) {
  const int nb = static_cast<int>(batches_.size());
  tbb::parallel_for(
      tbb::blocked_range<int>(0, nb, 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int q = r.begin(); q != r.end(); ++q)
          run_batch(batches_[static_cast<std::size_t>(q)], record);
      },
      tbb::simple_partitioner{});
  for (const Batch& bt : batches_)
    if (bt.outran && bt.fault == Fault::none)
      return false;
  return true;
}

void OrbScheme::subiterate(bool record) {
  if (subits_ % nsubit_ == 0)
    regrid();
  const std::size_t nl = ranges_.size() - 1;
  const std::size_t n = p_.size();
  bool fresh = false; // rows built for this sub-iteration
  if (time_to_contact_) {
    // Speed bounds, and candidates long enough that every pair able to touch within dt_sp is
    // one: the skin must cover two particles' reach (it returns to the scene's at the regrid).
    speed_.resize(n);
    double reach = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      double ax = model_.gravity[0], ay = model_.gravity[1], az = model_.gravity[2];
      if (ext_.active())
        ax += ext_.x[i] * p_.inv_mass[i], ay += ext_.y[i] * p_.inv_mass[i],
            az += ext_.z[i] * p_.inv_mass[i];
      speed_[i] = std::sqrt(p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i]) +
                  std::sqrt(ax * ax + ay * ay + az * az) * (hprev_[i] + dt_sp_);
      reach = std::max(reach, speed_[i] * dt_sp_);
    }
    if (2.1 * reach > skin_ && skin_ < skin_cap_) {
      skin_ = std::min(2.1 * reach, skin_cap_);
      pairs_valid_ = false;
    }
  }
  {
    if (!pairs_valid_ || rows_expire())
      rebuild_pairs(), fresh = true;
    if (off_.size() != n + 1) {
      PhaseTimer::Scope t(timer_, Phase::neighbor);
      derive_rows();
    }
  }
  PhaseTimer::Scope t(timer_, Phase::force);
  // Frozen copies (the ghosts' state, and the rollback point of a retry).
  gx_ = p_.x, gy_ = p_.y, gz_ = p_.z, gvx_ = p_.vx, gvy_ = p_.vy, gvz_ = p_.vz, ghp_ = hprev_;
  if (record) {
    sx_.resize(n), sy_.resize(n), sz_.resize(n);
    for (std::size_t i = 0; i < n; ++i)
      sx_[i] = geom_.wrap(p_.x[i], 0), sy_[i] = geom_.wrap(p_.y[i], 1),
      sz_[i] = geom_.wrap(p_.z[i], 2);
    svx_.resize(n), svy_.resize(n), svz_.resize(n);
    smass_ = p_.mass, sid_ = p_.id, sradius_ = p_.radius;
    sleaf_.resize(n), sdt_.resize(n);
    for (std::size_t l = 0; l < nl; ++l)
      for (std::uint32_t i = ranges_[l]; i < ranges_[l + 1]; ++i)
        sleaf_[i] = static_cast<std::int64_t>(l);
  }
  // Local step of each leaf: fine if one of its particles has a partner (own or other leaf)
  // within the proximity distance.
  const double prox = 0.5 * scene_.dem.proximity_radii;
  near_.assign(n, 0);
  auto test = [&](std::uint32_t a, std::uint32_t c) {
    const double dx = geom_.image(p_.x[c] - p_.x[a], 0), dy = geom_.image(p_.y[c] - p_.y[a], 1),
                 dz = geom_.image(p_.z[c] - p_.z[a], 2);
    const double d = prox * (p_.radius[a] + p_.radius[c]);
    if (dx * dx + dy * dy + dz * dz < d * d)
      near_[a] = near_[c] = 1;
  };
  if (time_to_contact_) {
    // dem.local_dt = "time_to_contact" (the seed paper's suggested relative-distance estimate):
    // a particle is near when some gap, to a contact candidate or to a wall, could close within
    // dt_sp at its current speed plus what gravity and its external force add (speed_, above).
    // Any pair that could touch is a candidate: the skin covers two reaches.
    for (std::size_t q = 0; q < ca_.size(); ++q) {
      const std::uint32_t a = ca_[q], c = cb_[q];
      const double dx = geom_.image(p_.x[c] - p_.x[a], 0), dy = geom_.image(p_.y[c] - p_.y[a], 1),
                   dz = geom_.image(p_.z[c] - p_.z[a], 2);
      const double reach = p_.radius[a] + p_.radius[c] + (speed_[a] + speed_[c]) * dt_sp_;
      if (dx * dx + dy * dy + dz * dz < reach * reach)
        near_[a] = near_[c] = 1;
    }
    for (int a = 0; a < 3; ++a) {
      if (geom_.periodic[a])
        continue;
      const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
      for (std::size_t i = 0; i < n; ++i) {
        const double d = p_.radius[i] + speed_[i] * dt_sp_;
        near_[i] |= pos[i] - geom_.lo[a] < d || geom_.hi[a] - pos[i] < d;
      }
    }
  } else {
    if (prox_from_pairs_) {
      for (std::size_t q = 0; q < pa_.size(); ++q)
        test(pa_[q], pb_[q]);
    } else {
      for (std::uint32_t a = 0; a < n; ++a)
        for (std::uint32_t c = a + 1; c < n; ++c)
          test(a, c);
    }
    // A wall is a partner too: a particle whose centre is closer than proximity_radii radii to
    // a wall (without this, a leaf near a floor took coarse steps straight into it).
    for (int a = 0; a < 3; ++a) {
      if (geom_.periodic[a])
        continue;
      const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
      for (std::size_t i = 0; i < n; ++i) {
        const double d = 2.0 * prox * p_.radius[i];
        near_[i] |= pos[i] - geom_.lo[a] < d || geom_.hi[a] - pos[i] < d;
      }
    }
  }
  leaf_fine_.assign(nl, 0);
  const unsigned char* near = near_.data();
  for (std::size_t l = 0; l < nl; ++l) {
    unsigned char any = 0; // a local: stores through a char pointer would alias everything
    for (std::uint32_t i = ranges_[l]; i < ranges_[l + 1]; ++i)
      any |= near[i];
    leaf_fine_[l] = any;
  }
  const bool can_refine = model_.dt < dt_sp_;
  const FineSteps steps = fine_steps(dt_sp_, model_.dt);
  const std::int64_t K_fine = steps.K;
  const double h_fine = steps.h;
  const double h_fine_last = steps.h_last;
  // Batches: runs of consecutive leaves with the same step, cut at about `grain` particles so
  // that every thread gets several (the arithmetic does not depend on the cuts).
  const auto threads = static_cast<std::size_t>(tbb::this_task_arena::max_concurrency());
  const std::size_t grain = std::max<std::size_t>(256, n / (4 * std::max<std::size_t>(threads, 1)));
  batches_.clear();
  for (std::size_t l = 0; l < nl; ++l) {
    const bool fine = leaf_fine_[l] && can_refine;
    const std::uint32_t b = ranges_[l], e = ranges_[l + 1];
    if (b == e)
      continue;
    const std::int64_t K = fine ? K_fine : 1;
    if (batches_.empty() || batches_.back().K != K || batches_.back().e != b ||
        batches_.back().e - batches_.back().b >= grain) {
      Batch bt;
      bt.b = b, bt.K = K;
      bt.h = fine ? h_fine : dt_sp_;
      bt.h_last = fine ? h_fine_last : dt_sp_;
      batches_.push_back(bt);
    }
    batches_.back().e = e;
  }
  if (record)
    for (const Batch& bt : batches_)
      for (std::uint32_t i = bt.b; i < bt.e; ++i)
        sdt_[i] = dt_sp_ / static_cast<double>(bt.K);
  bind_rows();
  while (!attempt(record)) {
    // A fine leaf outran its rows (a collision sped a particle up): roll back, rebuild, redo;
    // if the rows were already fresh, with twice the skin (kept for the rest of the run).
    if (fresh && skin_ >= skin_cap_)
      throw RunError(fmt::format("t = {:.9g} s: a particle moves more than half the neighbor "
                                 "skin in one sub-iteration even with the largest skin the "
                                 "periodic box allows ({:.4g} m): raise dem.nsubit",
                                 time(), skin_));
    p_.x = gx_, p_.y = gy_, p_.z = gz_, p_.vx = gvx_, p_.vy = gvy_, p_.vz = gvz_, hprev_ = ghp_;
    if (fresh)
      skin_ = std::min(2.0 * skin_, skin_cap_);
    fresh = true;
    ++retries_;
    rebuild_pairs();
    derive_rows();
    bind_rows();
  }
  // Counters, reduced in batch order.
  for (const Batch& bt : batches_) {
    if (bt.fault != Fault::none) {
      const std::size_t k = bt.fault_index;
      throw RunError(fmt::format(
          "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {}", time(),
          subits_, p_.id[k], p_.x[k], p_.y[k], p_.z[k],
          bt.fault == Fault::nan
              ? "position or velocity is not finite (NaN/inf): the step is unstable"
              : fmt::format("left the domain through a wall (coordinate {:.6g} m)",
                            bt.fault_value)));
    }
    particle_steps_ += static_cast<std::int64_t>(bt.e - bt.b) * bt.K;
    pair_evaluations_ += bt.evals_per_step * bt.K;
    overlap_violations_ += bt.violations;
    max_overlap_ratio_ = std::max(max_overlap_ratio_, bt.max_ratio);
    if (cost_weights_)
      for (std::uint32_t i = bt.b; i < bt.e; ++i)
        cost_[i] += static_cast<double>(bt.K);
  }
  std::int64_t fine = 0, busy = 0;
  for (std::size_t l = 0; l < nl; ++l) {
    if (ranges_[l + 1] == ranges_[l])
      continue;
    ++busy;
    fine += leaf_fine_[l];
    leaf_steps_[l] += leaf_fine_[l] && can_refine ? K_fine : 1;
  }
  fine_count_ += fine;
  leaf_subits_ += busy;
  last_fine_fraction_ = busy > 0 ? static_cast<double>(fine) / static_cast<double>(busy) : 0.0;
  ++subits_;
  resort();
}

void OrbScheme::benchmark_leaf_subiteration(int leaf) {
  const auto l = static_cast<std::size_t>(leaf);
  Batch bt;
  bt.b = ranges_[l], bt.e = ranges_[l + 1];
  const FineSteps steps = fine_steps(dt_sp_, model_.dt);
  bt.K = steps.K;
  bt.h = steps.h;
  bt.h_last = steps.h_last;
  bt.a0 = static_cast<std::uint32_t>(std::lower_bound(active_.begin(), active_.end(), bt.b) -
                                     active_.begin());
  bt.a1 = static_cast<std::uint32_t>(std::lower_bound(active_.begin(), active_.end(), bt.e) -
                                     active_.begin());
  run_batch(bt, false);
}

void OrbScheme::benchmark_ghost_refresh() {
  gx_ = p_.x, gy_ = p_.y, gz_ = p_.z, gvx_ = p_.vx, gvy_ = p_.vy, gvz_ = p_.vz, ghp_ = hprev_;
  derive_rows();
}

void OrbScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                   std::span<const double> fz) {
  ext_.set(fx, fy, fz, p_.size());
}

void OrbScheme::replace_external_force(std::span<const double> fx, std::span<const double> fy,
                                       std::span<const double> fz) {
  // hprev_ was sized at construction; after a checkpoint restore it is the saved one.
  if (ext_.active() || !fx.empty())
    settle_owed_half_kick(p_.vx, p_.vy, p_.vz, p_.inv_mass,
                          std::span<const double>(hprev_).first(p_.size()), ext_.x, ext_.y, ext_.z,
                          fx, fy, fz);
  set_external_force(fx, fy, fz);
}

OrbScheme::State OrbScheme::save_state() const {
  if (subits_ % nsubit_ != 0)
    throw RunError("orb checkpoint requested between regrid points (internal error)");
  State s;
  s.hprev = hprev_, s.cost = cost_, s.leaf_steps = leaf_steps_;
  s.fine_count = fine_count_, s.leaf_subits = leaf_subits_, s.subits = subits_;
  s.particle_steps = particle_steps_, s.pair_evaluations = pair_evaluations_, s.builds = builds_;
  s.regrids = regrids_, s.overlap_violations = overlap_violations_, s.retries = retries_;
  s.last_fine_fraction = last_fine_fraction_, s.max_overlap_ratio = max_overlap_ratio_;
  s.skin = skin_;
  s.pairs_valid = pairs_valid_, s.prox_from_pairs = prox_from_pairs_;
  if (pairs_valid_) {
    s.ca = ca_, s.cb = cb_, s.pa = pa_, s.pb = pb_;
    s.x_ref = xr_, s.y_ref = yr_, s.z_ref = zr_;
  }
  return s;
}

void OrbScheme::restore_state(State s) {
  const std::size_t n = p_.size();
  if (s.hprev.size() != n || s.cost.size() != n || s.subits < 0 || s.subits % nsubit_ != 0)
    throw RunError("checkpoint: the orb state does not fit the particles or dem.nsubit");
  if (s.pairs_valid) {
    bool ok = s.ca.size() == s.cb.size() && s.pa.size() == s.pb.size() && s.x_ref.size() == n &&
              s.y_ref.size() == n && s.z_ref.size() == n;
    for (const auto* v : {&s.ca, &s.cb, &s.pa, &s.pb})
      for (std::uint32_t i : *v)
        ok = ok && i < n;
    if (!ok)
      throw RunError("checkpoint: the orb candidate pairs do not fit the particles");
  }
  hprev_ = std::move(s.hprev), cost_ = std::move(s.cost), leaf_steps_ = std::move(s.leaf_steps);
  fine_count_ = s.fine_count, leaf_subits_ = s.leaf_subits, subits_ = s.subits;
  particle_steps_ = s.particle_steps, pair_evaluations_ = s.pair_evaluations, builds_ = s.builds;
  regrids_ = s.regrids, overlap_violations_ = s.overlap_violations, retries_ = s.retries;
  last_fine_fraction_ = s.last_fine_fraction, max_overlap_ratio_ = s.max_overlap_ratio;
  if (s.skin > 0.0)
    skin_ = s.skin;
  pairs_valid_ = s.pairs_valid, prox_from_pairs_ = s.prox_from_pairs;
  ca_ = std::move(s.ca), cb_ = std::move(s.cb), pa_ = std::move(s.pa), pb_ = std::move(s.pb);
  xr_ = std::move(s.x_ref), yr_ = std::move(s.y_ref), zr_ = std::move(s.z_ref);
  if (!pairs_valid_)
    ca_.clear(), cb_.clear(), pa_.clear(), pb_.clear(), xr_.clear(), yr_.clear(), zr_.clear();
  off_.clear(); // rows are derived again
}

LeafStepStats OrbScheme::take_interval_stats() {
  LeafStepStats s;
  std::int64_t lo = std::numeric_limits<std::int64_t>::max(), hi = 0, sum = 0, count = 0;
  for (auto& v : leaf_steps_) {
    if (v > 0)
      lo = std::min(lo, v), hi = std::max(hi, v), sum += v, ++count;
    v = 0;
  }
  if (count > 0) {
    s.steps_min = static_cast<double>(lo), s.steps_max = static_cast<double>(hi);
    s.steps_mean = static_cast<double>(sum) / static_cast<double>(count);
  }
  s.fine_fraction =
      leaf_subits_ > 0 ? static_cast<double>(fine_count_) / static_cast<double>(leaf_subits_) : 0.0;
  fine_count_ = leaf_subits_ = 0;
  return s;
}

} // namespace cfddem::dem
