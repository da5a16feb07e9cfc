// The one-rank steps of the orb scheme (dem/orb_scheme.hpp): the regrid over the whole store,
// the re-sort of particles that left their leaf, and the persistent candidate pairs (rebuilt
// when some particle may outrun them, remapped when the store is re-sorted) with the rows
// derived from them.
#include <algorithm>
#include <cmath>
#include <numeric>

#include <fmt/format.h>

#include "core/error.hpp"
#include "dem/cell_list.hpp"
#include "dem/contact_history.hpp"
#include "dem/orb_local_rows.hpp"
#include "dem/orb_rank_part.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/scheme_support.hpp"
#include "dem/verlet_list.hpp"

namespace cfddem::dem {

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
  permute(hprev_), permute(cost_), permute(pairs_.xr), permute(pairs_.yr), permute(pairs_.zr);
  ext_.permute(order);
  relabel_pairs(order);
}

// The store was reordered (slot k holds the particle of old slot old_slot[k]): the candidate
// pairs follow their particles, and the rows must be derived again.
void OrbScheme::relabel_pairs(std::span<const std::uint32_t> old_slot) {
  const std::size_t n = old_slot.size();
  scratch_.resize(n);
  for (std::size_t k = 0; k < n; ++k)
    scratch_[old_slot[k]] = static_cast<std::uint32_t>(k);
  for (auto* v : {&pairs_.ca, &pairs_.cb, &pairs_.pa, &pairs_.pb})
    for (auto& i : *v)
      i = scratch_[i];
  drop_rows();
  global_.stale = true;
}

// At a regrid point: the particles wrapped into the box, the reference positions moved by the
// same period (so the displacement since the last neighbor build is unchanged, and the pairs'
// split into raw and imaged separations is redone: global_stream). A skin grown by a retry lasts
// until here: rows built with it stay valid (they hold more pairs), and the next build uses the
// scene's skin again. On R ranks the owned particles alone (the ghosts are gone; the rows are
// built again).
void OrbScheme::wrap_positions() {
  skin_ = model_.skin;
  const std::size_t n = p_.size();
  for (std::size_t i = 0; i < n; ++i) {
    const double wx = geom_.wrap(p_.x[i], 0), wy = geom_.wrap(p_.y[i], 1),
                 wz = geom_.wrap(p_.z[i], 2);
    if (!pairs_.xr.empty())
      pairs_.xr[i] += wx - p_.x[i], pairs_.yr[i] += wy - p_.y[i], pairs_.zr[i] += wz - p_.z[i];
    p_.x[i] = wx, p_.y[i] = wy, p_.z[i] = wz;
  }
  global_.stale = true;
  // One rank: the shift may round the displacements, so the travel bound starts again from an
  // exact measurement, which also says whether a particle is now skin/2 from the pairs' build
  // (what the last step's test said, on the state alone: a restart measures alike).
  if (pairs_.valid && !rank_)
    global_.moved = measure_travel() > 0;
}

void OrbScheme::regrid() {
  PhaseTimer::Scope t(timer_, Phase::regrid);
  wrap_positions();
  const std::size_t n = p_.size();
  bool use_cost = cfg_.cost_weights;
  if (use_cost) {
    double total = 0.0;
    for (double c : cost_)
      total += c;
    use_cost = total > 0.0; // the first regrid has no measurement yet: count
  }
  // With a gas, cuts lie on fluid cell faces (orb_snap_grid).
  decomp_.tree = partition::OrbTree::build(
      p_.x, p_.y, p_.z, use_cost ? std::span<const double>(cost_) : std::span<const double>(),
      domain_, partition::OrbOptions{scene_.partition.orb_levels, orb_snap_grid(scene_)});
  const auto order = decomp_.tree.order();
  apply_permutation(order);
  std::fill(cost_.begin(), cost_.end(), 0.0);
  const auto leaves = decomp_.tree.leaves();
  leaves_.range.assign(leaves.size() + 1, 0);
  for (std::size_t l = 0; l < leaves.size(); ++l)
    leaves_.range[l + 1] = leaves[l].end;
  leaves_.id.resize(leaves.size());
  std::iota(leaves_.id.begin(), leaves_.id.end(), 0);
  decomp_.owner.assign(leaves.size(), 0); // every leaf on this rank
  decomp_.load.assign(1, static_cast<double>(n));
  if (stats_.leaf_steps.size() != leaves.size())
    stats_.leaf_steps.assign(leaves.size(), 0);
  ++stats_.regrids;
}

// The ORB leaf that holds particle i at its wrapped position; a RunError naming the particle
// where none does (it left the domain).
std::uint32_t OrbScheme::leaf_holding(std::size_t i) const {
  const int k =
      decomp_.tree.locate(geom_.wrap(p_.x[i], 0), geom_.wrap(p_.y[i], 1), geom_.wrap(p_.z[i], 2));
  if (k < 0)
    throw RunError(fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left "
                               "the domain",
                               time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i]));
  return static_cast<std::uint32_t>(k);
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
  const std::size_t nl = leaves_.range.size() - 1;
  std::vector<std::uint32_t>& target = leaves_.of; // the leaf holding each slot's particle
  target.resize(n);
  bool moved = false;
  const auto leaves = decomp_.tree.leaves();
  const double* __restrict xs = p_.x.data();
  const double* __restrict ys = p_.y.data();
  const double* __restrict zs = p_.z.data();
  for (std::size_t l = 0; l < nl; ++l) {
    const partition::Aabb box = leaves[l].box;
    const std::uint32_t b = leaves_.range[l], e = leaves_.range[l + 1];
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
      std::uint32_t k = static_cast<std::uint32_t>(l);
      if (!(box.lo[0] <= px && px < box.hi[0] && box.lo[1] <= py && py < box.hi[1] &&
            box.lo[2] <= pz && pz < box.hi[2]))
        k = leaf_holding(i);
      target[i] = k;
      moved |= k != l;
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
    if (!pairs_.xr.empty())
      std::swap(pairs_.xr[a], pairs_.xr[c]), std::swap(pairs_.yr[a], pairs_.yr[c]),
          std::swap(pairs_.zr[a], pairs_.zr[c]);
    ext_.swap(a, c);
    std::swap(target[a], target[c]);
    std::swap(origin[a], origin[c]);
  };
  for (std::size_t l = 0; l < nl; ++l) {
    std::uint32_t i = leaves_.range[l];
    while (true) {
      i = std::max(i, leaves_.range[l]); // a particle walked out of the front of leaf l
      if (i >= leaves_.range[l + 1])
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
          const std::uint32_t last = leaves_.range[j + 1] - 1;
          swap_slots(m, last);
          m = last;
          --leaves_.range[j + 1];
        }
      } else {
        for (std::size_t j = l; j > dest; --j) {
          const std::uint32_t first = leaves_.range[j];
          swap_slots(m, first);
          m = first;
          ++leaves_.range[j];
        }
      }
    }
  }
  relabel_pairs(origin); // old slot origin[k] is now slot k
}

// One rank, a regrid point after a held global interval (Global::hold), or its recorded
// sub-iteration: the store sorted into the ORB's leaves as they are, each particle into the leaf
// that holds it now (its wrapped position), stably: a function of the store's order and the
// positions alone, so a restart (whose checkpoint keeps the store's order and the ORB, not the
// leaves' ranges) sorts alike. Then the pair lists follow their particles.
void OrbScheme::sort_into_leaves() {
  const std::size_t n = p_.size(), nl = leaves_.id.size();
  std::vector<std::uint32_t>& leaf = leaves_.of;
  leaf.resize(n);
  std::vector<std::uint32_t> start(nl + 1, 0);
  for (std::size_t i = 0; i < n; ++i) {
    leaf[i] = leaf_holding(i);
    ++start[leaf[i] + 1];
  }
  for (std::size_t l = 0; l < nl; ++l)
    start[l + 1] += start[l];
  leaves_.range = start;
  std::vector<std::uint32_t> order(n);
  for (std::size_t i = 0; i < n; ++i)
    order[start[leaf[i]]++] = static_cast<std::uint32_t>(i);
  apply_permutation(order);
  for (std::size_t l = 0; l < nl; ++l)
    for (std::uint32_t i = leaves_.range[l]; i < leaves_.range[l + 1]; ++i)
      leaf[i] = static_cast<std::uint32_t>(l);
}

// True when some particle's displacement since the build plus its free flight over one
// sub-iteration exceeds skin/2: the rows are then rebuilt before the sub-iteration, in which the
// particle would likely outrun them. Positions and references are unwrapped alike (a regrid
// shifts both), so plain differences. (d + v dt)^2 <= 2 (d^2 + v^2 dt^2): the square roots are
// taken only for the few particles that fail that bound.
bool OrbScheme::rows_expire(std::size_t n, const std::array<const double*, 3>& ref) const {
  const double lim = 0.5 * skin_, lim2 = lim * lim, dt2 = cfg_.dt_sp * cfg_.dt_sp;
  const double* x = p_.x.data();
  const double* y = p_.y.data();
  const double* z = p_.z.data();
  const double* vx = p_.vx.data();
  const double* vy = p_.vy.data();
  const double* vz = p_.vz.data();
  const double* xr = ref[0];
  const double* yr = ref[1];
  const double* zr = ref[2];
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
    if (!(2.0 * (d2 + v2 * dt2) <= lim2) && !(std::sqrt(d2) + std::sqrt(v2) * cfg_.dt_sp <= lim))
      return true; // NaN expires the rows too
  }
  return false;
}

// One rank, a regrid point after a held global interval (particles wrapped and re-sorted into
// the leaves as they are): choose_global's decision under the proximity rule, without building
// the proximity candidates. The contact candidates within the proximity distance mark some of
// the fine leaves (mark_near's lower bound); only the particles of the other leaves are tested
// against every particle (a cell list of the proximity distance, or pair by pair where it does
// not fit the periodic box), each leaf until one of its particles is near, and the test stops
// once more than kGlobalFraction of the particles are in fine leaves. The same decision as the
// full candidates' (a leaf is fine if one of its particles is near a partner or a wall).
bool OrbScheme::held_global_decision() {
  PhaseTimer::Scope t(timer_, Phase::regrid);
  if (!global_allowed())
    return false;
  mark_near(true);
  mark_fine_leaves(rows_.near);
  const std::size_t n = p_.size(), nl = leaves_.id.size();
  const double bar = kGlobalFraction * static_cast<double>(owned_);
  std::size_t fine = 0;
  for (std::size_t k = 0; k < nl; ++k)
    fine += leaves_.fine[k] ? leaves_.range[k + 1] - leaves_.range[k] : 0;
  if (static_cast<double>(fine) > bar)
    return true;
  const double* x = p_.x.data();
  const double* y = p_.y.data();
  const double* z = p_.z.data();
  const double* r = p_.radius.data();
  const auto near = [&](std::uint32_t a, std::uint32_t c) {
    return a != c && within_proximity(separation2(a, c), r[a] + r[c], cfg_.prox);
  };
  CellList& cells = pairs_.cells;
  const bool binned = pairs_.prox_from_pairs;
  if (binned)
    cells.bin<true>(geom_, make_cell_grid(geom_, 2.0 * cfg_.prox * cfg_.r_max, n, 8.0), x, y, z, n);
  const std::uint32_t* items = cells.items().data();
  for (std::size_t k = 0; k < nl && !(static_cast<double>(fine) > bar); ++k) {
    if (leaves_.fine[k])
      continue;
    for (std::uint32_t i = leaves_.range[k]; i < leaves_.range[k + 1] && !leaves_.fine[k]; ++i) {
      bool found = false;
      if (binned) {
        cells.for_each_around(cells.coord<true>(x[i], 0), cells.coord<true>(y[i], 1),
                              cells.coord<true>(z[i], 2),
                              [&](std::uint32_t q) { found = found || near(i, items[q]); });
      } else {
        for (std::uint32_t c = 0; c < n && !found; ++c)
          found = near(i, c);
      }
      if (found)
        leaves_.fine[k] = 1, fine += leaves_.range[k + 1] - leaves_.range[k];
    }
  }
  return static_cast<double>(fine) > bar;
}

// |x_c - x_a|^2 by the minimum image.
double OrbScheme::separation2(std::uint32_t a, std::uint32_t c) const {
  const double dx = geom_.image(p_.x[c] - p_.x[a], 0), dy = geom_.image(p_.y[c] - p_.y[a], 1),
               dz = geom_.image(p_.z[c] - p_.z[a], 2);
  return dx * dx + dy * dy + dz * dz;
}

// One cell list over the whole store (indices binned, the store is not moved): contact
// candidates within r_a + r_b + skin and proximity candidates within prox (r_a + r_b)/2 + skin,
// each pair once, in a deterministic order. Proximity candidates are skipped when every particle
// is within the proximity distance of every other (prox_all) or the proximity distance reaches
// half a periodic length (prox_brute: tested pair by pair at each sub-iteration instead).
// With contact_only (a held global interval decides no mode) the contact candidates alone, over
// cells of the contact cutoff.
void OrbScheme::rebuild_pairs(bool contact_only) {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  const std::size_t n = p_.size();
  const DomainGeometry& g = geom_;
  const double prox = 0.5 * scene_.dem.proximity_radii;
  const double contact_cut = 2.0 * cfg_.r_max + skin_;
  const double prox_cut = 2.0 * prox * cfg_.r_max + skin_;
  bool prox_fits = true;
  for (int a = 0; a < 3; ++a)
    if (g.periodic[a] && 2.0 * prox_cut >= g.length[a])
      prox_fits = false;
  const bool prox_cells = prox_fits && !contact_only;
  const double cutoff = prox_cells ? std::max(contact_cut, prox_cut) : contact_cut;
  CellList& cells = pairs_.cells;
  cells.bin<true>(g, make_cell_grid(g, cutoff, n, 8.0), p_.x.data(), p_.y.data(), p_.z.data(), n);
  const std::uint32_t* items = cells.items().data();
  pairs_.ca.clear(), pairs_.cb.clear(), pairs_.pa.clear(), pairs_.pb.clear();
  if (cells.grid().half_stencil()) {
    // Each pair once (a cell against itself and its forward neighbours), over the binned
    // particles' data copied in cell order so that the inner loops read contiguous memory.
    cells.gather<4>({p_.x.data(), p_.y.data(), p_.z.data(), p_.radius.data()}, pairs_.sorted);
    const double* sx = pairs_.sorted[0].data();
    const double* sy = pairs_.sorted[1].data();
    const double* sz = pairs_.sorted[2].data();
    const double* sr = pairs_.sorted[3].data();
    auto test_sorted = [&](std::uint32_t a, std::uint32_t b) {
      const double dx = g.image(sx[b] - sx[a], 0), dy = g.image(sy[b] - sy[a], 1),
                   dz = g.image(sz[b] - sz[a], 2);
      const double r2 = dx * dx + dy * dy + dz * dz;
      const double rs = sr[a] + sr[b];
      const double pc = prox * rs + skin_;
      if (r2 < (rs + skin_) * (rs + skin_))
        pairs_.ca.push_back(items[a]), pairs_.cb.push_back(items[b]);
      if (prox_cells && r2 < pc * pc)
        pairs_.pa.push_back(items[a]), pairs_.pb.push_back(items[b]);
    };
    for (int cz = 0; cz < cells.grid().n[2]; ++cz)
      cells.for_each_forward_pair(
          cz, [](std::size_t) { return true; }, test_sorted);
  } else {
    // Fewer than three cells on an axis: each particle against the cells around its own
    // (periodic images collapsed), partners of higher index.
    const double* px = p_.x.data();
    const double* py = p_.y.data();
    const double* pz = p_.z.data();
    const double* pr = p_.radius.data();
    for (std::uint32_t i = 0; i < n; ++i)
      cells.for_each_around(cells.coord<true>(px[i], 0), cells.coord<true>(py[i], 1),
                            cells.coord<true>(pz[i], 2), [&](std::uint32_t q) {
                              const std::uint32_t j = items[q];
                              if (j <= i)
                                return;
                              const double dx = g.image(px[j] - px[i], 0),
                                           dy = g.image(py[j] - py[i], 1),
                                           dz = g.image(pz[j] - pz[i], 2);
                              const double r2 = dx * dx + dy * dy + dz * dz;
                              const double rs = pr[i] + pr[j];
                              if (r2 < (rs + skin_) * (rs + skin_))
                                pairs_.ca.push_back(i), pairs_.cb.push_back(j);
                              if (prox_cells && r2 < (prox * rs + skin_) * (prox * rs + skin_))
                                pairs_.pa.push_back(i), pairs_.pb.push_back(j);
                            });
  }
  pairs_.prox_from_pairs = prox_fits, pairs_.contact_only = contact_only;
  pairs_.xr = p_.x, pairs_.yr = p_.y, pairs_.zr = p_.z;
  pairs_.valid = true;
  global_.travel.reset();
  drop_rows();
  global_.stale = true;
  ++stats_.builds;
}

// The rows no longer fit the store (it was re-sorted, or the pairs rebuilt): with friction their
// history is kept by particle ids (the ids of the slots the rows were derived over) until the
// next derive_rows attaches it.
void OrbScheme::drop_rows() {
  if (model_.friction && rows_.off.size() == hist_.ids.size() + 1 &&
      hist_.hx.size() == rows_.nb.size()) {
    hist_.pending.append(collect_history(hist_.ids, rows_.off, rows_.nb, hist_.ids.size(), hist_.hx,
                                         hist_.hy, hist_.hz));
    hist_.hx.clear(), hist_.hy.clear(), hist_.hz.clear(), hist_.ids.clear();
  }
  rows_.off.clear();
}

// The tangential history by ids: that of the current rows, or the records awaiting rows (R
// ranks: this rank's owned rows').
ContactHistory OrbScheme::current_history() const {
  ContactHistory h = hist_.pending;
  if (rank_) {
    const auto off = rank_->rows.off();
    if (off.size() >= 1 && hist_.hx.size() == rank_->rows.nb().size())
      h.append(collect_history(hist_.ids, off, rank_->rows.nb(), off.size() - 1, hist_.hx, hist_.hy,
                               hist_.hz));
    return h;
  }
  if (rows_.off.size() == hist_.ids.size() + 1 && hist_.hx.size() == rows_.nb.size())
    h.append(collect_history(hist_.ids, rows_.off, rows_.nb, hist_.ids.size(), hist_.hx, hist_.hy,
                             hist_.hz));
  return h;
}

// Rows of the current leaves from the contact candidates (after a build or a re-sort); with
// friction the history follows the pairs (drop_rows, then attached by ids).
void OrbScheme::derive_rows() {
  if (model_.friction)
    drop_rows();
  const std::size_t n = p_.size();
  const std::size_t nl = leaves_.range.size() - 1;
  leaves_.of.resize(n);
  for (std::size_t l = 0; l < nl; ++l)
    for (std::uint32_t i = leaves_.range[l]; i < leaves_.range[l + 1]; ++i)
      leaves_.of[i] = static_cast<std::uint32_t>(l);
  std::vector<std::uint32_t>& own = scratch_;
  own.assign(n, 0);
  rows_.off.assign(n + 1, 0);
  for (std::size_t q = 0; q < pairs_.ca.size(); ++q) {
    const std::uint32_t a = pairs_.ca[q], b = pairs_.cb[q];
    ++rows_.off[a + 1], ++rows_.off[b + 1];
    if (leaves_.of[a] == leaves_.of[b])
      ++own[a], ++own[b];
  }
  for (std::size_t i = 0; i < n; ++i)
    rows_.off[i + 1] += rows_.off[i];
  rows_.mid.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    rows_.mid[i] = rows_.off[i] + own[i];
  rows_.nb.resize(rows_.off[n]);
  std::vector<std::uint32_t>& fo = own; // fill cursors: own segment, then ghost segment
  std::vector<std::uint32_t>& fg = fill_;
  fg.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    fo[i] = rows_.off[i], fg[i] = rows_.mid[i];
  for (std::size_t q = 0; q < pairs_.ca.size(); ++q) {
    const std::uint32_t a = pairs_.ca[q], b = pairs_.cb[q];
    if (leaves_.of[a] == leaves_.of[b]) {
      rows_.nb[fo[a]++] = b, rows_.nb[fo[b]++] = a;
    } else {
      rows_.nb[fg[a]++] = b, rows_.nb[fg[b]++] = a;
    }
  }
  rows_.active.clear();
  rows_.own_before.resize(n + 1);
  rows_.own_before[0] = 0;
  for (std::size_t i = 0; i < n; ++i)
    rows_.own_before[i + 1] = rows_.own_before[i] + (rows_.mid[i] - rows_.off[i]);
  for (std::size_t i = 0; i < n; ++i) {
    sort_by_id(rows_.nb.data() + rows_.off[i], rows_.nb.data() + rows_.mid[i], p_.id.data());
    sort_by_id(rows_.nb.data() + rows_.mid[i], rows_.nb.data() + rows_.off[i + 1], p_.id.data());
    if (rows_.off[i + 1] > rows_.off[i])
      rows_.active.push_back(static_cast<std::uint32_t>(i));
  }
  // Only particles with a row get their contact force rewritten each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (model_.friction) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
    attach_history(std::move(hist_.pending), p_.id, rows_.off, rows_.nb, n, hist_.hx, hist_.hy,
                   hist_.hz);
    hist_.pending = ContactHistory{};
    hist_.ids = p_.id;
  }
}

// Per particle: whether some partner (another particle, or a wall: mark_walls) is within the
// proximity distance, or with dem.local_dt = "time_to_contact" could touch it within dt_sp. The
// candidate pairs hold every such pair (their skin covers the distance, or two reaches).
// With contact_bound (the proximity rule over contact candidates alone, Pairs::contact_only) the
// contact candidates are tested instead: some of the near particles, none that is not.
void OrbScheme::mark_near(bool contact_bound) {
  const std::size_t n = p_.size();
  std::vector<unsigned char>& near = rows_.near;
  near.assign(n, 0);
  const double* r = p_.radius.data();
  if (cfg_.time_to_contact) {
    for (std::size_t q = 0; q < pairs_.ca.size(); ++q) {
      const std::uint32_t a = pairs_.ca[q], c = pairs_.cb[q];
      if (within_reach(separation2(a, c), r[a] + r[c], speed_[a] + speed_[c], cfg_.dt_sp))
        near[a] = near[c] = 1;
    }
  } else {
    auto test = [&](std::uint32_t a, std::uint32_t c) {
      if (within_proximity(separation2(a, c), r[a] + r[c], cfg_.prox))
        near[a] = near[c] = 1;
    };
    if (contact_bound) {
      for (std::size_t q = 0; q < pairs_.ca.size(); ++q)
        test(pairs_.ca[q], pairs_.cb[q]);
    } else if (pairs_.prox_from_pairs) {
      for (std::size_t q = 0; q < pairs_.pa.size(); ++q)
        test(pairs_.pa[q], pairs_.pb[q]);
    } else {
      for (std::uint32_t a = 0; a < n; ++a)
        for (std::uint32_t c = a + 1; c < n; ++c)
          test(a, c);
    }
  }
  mark_walls(near);
}

} // namespace cfddem::dem
