#include "dem/orb_scheme.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include "core/error.hpp"

namespace cfddem::dem {

namespace {
enum class Fault { none = 0, nan, left_domain };
} // namespace

// Everything one leaf touches during a sub-iteration: own particles first (n_own), then the
// frozen ghosts; the local neighbor list (own-own pairs once, own-ghost pairs once); and the
// leaf's counters. Only the task running the leaf writes it.
struct OrbScheme::Workspace {
  std::vector<double> x, y, z, vx, vy, vz, r, m, im, hp, fx, fy, fz, x0, y0, z0;
  std::vector<double> gx, gy, gz; // own: gravity + external force / m (external force only)
  std::vector<double> sx, sy, sz, svx, svy, svz; // recorded state (own)
  std::vector<std::uint32_t> oi, oj, gi, gj;     // own-own and own-ghost pairs
  std::vector<std::uint32_t> sorted;
  std::size_t n_own = 0;
  std::int64_t steps = 0, pair_evals = 0, builds = 0, violations = 0;
  bool fine = false;
  double max_ratio = 0.0;
  Fault fault = Fault::none;
  std::uint32_t fault_index = 0;
  double fault_value = 0.0;
};

OrbScheme::~OrbScheme() = default;

OrbScheme::OrbScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain),
      model_(make_step_model(scene, particles)) {
  if (model_.friction)
    throw ConfigError("scene key 'dem.scheme'",
                      "\"orb\" supports frictionless contacts only (dem.friction and "
                      "dem.wall_friction must be 0); use \"explicit\"");
  domain_ = partition::Aabb{scene.domain.lo, scene.domain.hi};
  for (std::size_t i = 0; i < p_.size(); ++i) r_max_ = std::max(r_max_, p_.radius[i]);
  if (p_.size() == 0) r_max_ = model_.r_min;
  nsubit_ = scene.dem.nsubit;
  dt_sp_ = scene.dem.regrid_interval / static_cast<double>(nsubit_);
  halo_ = 2.0 * r_max_ + 2.0 * model_.skin;
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && geom_.length[a] <= 2.0 * (2.0 * r_max_ + model_.skin))
      throw RunError(fmt::format("periodic axis {} is {:.4g} m long, not more than twice the "
                                 "neighbor cutoff {:.4g} m",
                                 a, geom_.length[a], 2.0 * r_max_ + model_.skin));
  hprev_.assign(p_.size(), 0.0);
}

void OrbScheme::start() {
  // v holds the synchronised v(0): the first kick is a(0) (0 + h/2), velocity Verlet's.
  hprev_.assign(p_.size(), 0.0);
  subits_ = 0;
}

void OrbScheme::regrid() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  for (std::size_t i = 0; i < p_.size(); ++i) {
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1);
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  }
  tree_ = partition::OrbTree::build(p_.x, p_.y, p_.z, {}, domain_,
                                    partition::OrbOptions{scene_.partition.orb_levels, {}});
  const auto order = tree_.order();
  p_.permute(order);
  std::vector<double> h(hprev_.size());
  for (std::size_t k = 0; k < order.size(); ++k) h[k] = hprev_[order[k]];
  hprev_.swap(h);
  permute_external(order);
  const auto leaves = tree_.leaves();
  ranges_.assign(leaves.size() + 1, 0);
  for (std::size_t l = 0; l < leaves.size(); ++l) ranges_[l + 1] = leaves[l].end;
  if (leaf_steps_.size() != leaves.size()) leaf_steps_.assign(leaves.size(), 0);
  work_.resize(leaves.size());
  ++regrids_;
}

// Counting sort by the leaf that now holds each particle (stable: a leaf keeps its order).
void OrbScheme::resort() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  const std::size_t n = p_.size();
  const std::size_t nl = ranges_.size() - 1;
  std::vector<std::uint32_t> leaf_of(n), count(nl + 1, 0);
  bool moved = false;
  for (std::size_t l = 0; l < nl; ++l)
    for (std::uint32_t i = ranges_[l]; i < ranges_[l + 1]; ++i) {
      const int k = tree_.locate(p_.x[i], p_.y[i], p_.z[i]);
      if (k < 0)
        throw RunError(fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left "
                                   "the domain",
                                   time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i]));
      leaf_of[i] = static_cast<std::uint32_t>(k);
      moved |= static_cast<std::size_t>(k) != l;
      ++count[static_cast<std::size_t>(k) + 1];
    }
  if (!moved) return;
  for (std::size_t l = 0; l < nl; ++l) count[l + 1] += count[l];
  ranges_.assign(count.begin(), count.end());
  std::vector<std::uint32_t> order(n);
  for (std::size_t i = 0; i < n; ++i) order[count[leaf_of[i]]++] = static_cast<std::uint32_t>(i);
  p_.permute(order);
  std::vector<double> h(n);
  for (std::size_t k = 0; k < n; ++k) h[k] = hprev_[order[k]];
  hprev_.swap(h);
  permute_external(order);
}

void OrbScheme::permute_external(std::span<const std::uint32_t> order) {
  if (!external_) return;
  for (auto* v : {&ex_, &ey_, &ez_}) {
    std::vector<double> out(order.size());
    for (std::size_t k = 0; k < order.size(); ++k) out[k] = (*v)[order[k]];
    v->swap(out);
  }
}

void OrbScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                   std::span<const double> fz) {
  external_ = !fx.empty();
  if (!external_) {
    ex_.clear(), ey_.clear(), ez_.clear();
    return;
  }
  if (fx.size() != p_.size() || fy.size() != p_.size() || fz.size() != p_.size())
    throw std::invalid_argument("set_external_force: one value per particle expected");
  ex_.assign(fx.begin(), fx.end());
  ey_.assign(fy.begin(), fy.end());
  ez_.assign(fz.begin(), fz.end());
}

void OrbScheme::run_leaf(int leaf, bool record, Workspace& w) const {
  const auto l = static_cast<std::size_t>(leaf);
  const std::uint32_t b = ranges_[l], e = ranges_[l + 1];
  const bool ext = external_;
  w.n_own = e - b;
  w.steps = w.pair_evals = w.builds = w.violations = 0;
  w.fine = false;
  w.max_ratio = 0.0;
  w.fault = Fault::none;
  if (w.n_own == 0) return;
  auto clear = [](auto&... v) { (v.clear(), ...); };
  clear(w.x, w.y, w.z, w.vx, w.vy, w.vz, w.r, w.m, w.im, w.hp);
  auto push = [&](std::uint32_t i, double sx, double sy, double sz) {
    w.x.push_back(p_.x[i] + sx), w.y.push_back(p_.y[i] + sy), w.z.push_back(p_.z[i] + sz);
    w.vx.push_back(p_.vx[i]), w.vy.push_back(p_.vy[i]), w.vz.push_back(p_.vz[i]);
    w.r.push_back(p_.radius[i]), w.m.push_back(p_.mass[i]), w.im.push_back(p_.inv_mass[i]);
    w.hp.push_back(hprev_[i]);
  };
  for (std::uint32_t i = b; i < e; ++i) push(i, 0.0, 0.0, 0.0);
  if (external_) {
    // Body acceleration of the own particles: gravity + the external (gas) force / m.
    clear(w.gx, w.gy, w.gz);
    for (std::uint32_t i = b; i < e; ++i) {
      w.gx.push_back(model_.gravity[0] + ex_[i] * p_.inv_mass[i]);
      w.gy.push_back(model_.gravity[1] + ey_[i] * p_.inv_mass[i]);
      w.gz.push_back(model_.gravity[2] + ez_[i] * p_.inv_mass[i]);
    }
  }
  // Ghosts: particles of other leaves (through each periodic image) within the halo of the box.
  // Copies of the own leaf's periodic images are not needed: own-own pairs use minimum image.
  const partition::Aabb box = tree_.leaves()[l].box;
  const partition::Aabb query = box.grown(halo_);
  for (const auto& img : tree_.leaf_images_overlapping(query, geom_.periodic)) {
    if (img.leaf == leaf) continue;
    const double sx = -img.shift[0] * geom_.length[0], sy = -img.shift[1] * geom_.length[1],
                 sz = -img.shift[2] * geom_.length[2];
    const auto gl = static_cast<std::size_t>(img.leaf);
    for (std::uint32_t i = ranges_[gl]; i < ranges_[gl + 1]; ++i)
      if (query.contains_closed({p_.x[i] + sx, p_.y[i] + sy, p_.z[i] + sz})) push(i, sx, sy, sz);
  }
  const std::size_t n = w.x.size(), no = w.n_own;
  w.fx.assign(no, 0.0), w.fy.assign(no, 0.0), w.fz.assign(no, 0.0);
  const double skin = model_.skin;
  const double prox = scene_.dem.proximity_radii * 0.5;

  // Sort-and-sweep along an axis on which own-own separations need no periodic image (then the
  // raw coordinate difference bounds the distance); if every axis wraps (a leaf spanning the
  // box, L = 0 say), every pair is tested: O(n^2), acceptable for the small leaves this scheme
  // is meant for. The scan radius covers the contact cutoff and the proximity test.
  int axis = -1;
  for (int a = 0; a < 3; ++a)
    if ((!geom_.periodic[a] || box.extent(a) + 2.0 * skin < geom_.half[a]) &&
        (axis < 0 || box.extent(a) > box.extent(axis)))
      axis = a;
  const std::vector<double>& key = axis == 1 ? w.y : axis == 2 ? w.z : w.x;
  const double scan = std::max(2.0 * r_max_ + skin, 2.0 * prox * r_max_);
  const DomainGeometry g = geom_;
  auto build = [&](bool proximity) {
    clear(w.oi, w.oj, w.gi, w.gj);
    w.sorted.resize(n);
    std::iota(w.sorted.begin(), w.sorted.end(), 0u);
    if (axis >= 0)
      std::sort(w.sorted.begin(), w.sorted.end(), [&](std::uint32_t i, std::uint32_t j) {
        return key[i] < key[j] || (key[i] == key[j] && i < j);
      });
    for (std::size_t s = 0; s < n; ++s) {
      const std::uint32_t i = w.sorted[s];
      for (std::size_t t = s + 1; t < n; ++t) {
        const std::uint32_t j = w.sorted[t];
        if (axis >= 0 && key[j] - key[i] >= scan) break;
        const bool own_i = i < no, own_j = j < no;
        if (!own_i && !own_j) continue;
        double dx = w.x[j] - w.x[i], dy = w.y[j] - w.y[i], dz = w.z[j] - w.z[i];
        if (own_i && own_j) dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
        const double r2 = dx * dx + dy * dy + dz * dz;
        const double rs = w.r[i] + w.r[j];
        if (proximity && r2 < prox * rs * prox * rs) w.fine = true;
        if (r2 >= (rs + skin) * (rs + skin)) continue;
        if (own_i && own_j) {
          w.oi.push_back(std::min(i, j)), w.oj.push_back(std::max(i, j));
        } else {
          w.gi.push_back(own_i ? i : j), w.gj.push_back(own_i ? j : i);
        }
      }
    }
    w.x0.assign(w.x.begin(), w.x.begin() + static_cast<std::ptrdiff_t>(no));
    w.y0.assign(w.y.begin(), w.y.begin() + static_cast<std::ptrdiff_t>(no));
    w.z0.assign(w.z.begin(), w.z.begin() + static_cast<std::ptrdiff_t>(no));
    ++w.builds;
  };
  build(true);

  // Local step: the fine step near a partner, else one step of dt_sp. K = ceil(dt_sp / dt)
  // (a relative slack of 1e-9 absorbs rounding when dt divides dt_sp); the last step is
  // shortened to dt_sp - (K-1) dt so that the leaf lands exactly on the sub-iteration's end.
  std::int64_t K = 1;
  double h = dt_sp_, h_last = dt_sp_;
  if (w.fine && model_.dt < dt_sp_) {
    K = std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(dt_sp_ / model_.dt - 1e-9)));
    h = model_.dt;
    h_last = dt_sp_ - static_cast<double>(K - 1) * model_.dt;
  }
  const StepModel& m = model_;
  const double lim = m.max_overlap;
  if (record) {
    w.sx.assign(w.x.begin(), w.x.begin() + static_cast<std::ptrdiff_t>(no));
    w.sy.assign(w.y.begin(), w.y.begin() + static_cast<std::ptrdiff_t>(no));
    w.sz.assign(w.z.begin(), w.z.begin() + static_cast<std::ptrdiff_t>(no));
    w.svx.resize(no), w.svy.resize(no), w.svz.resize(no);
  }
  for (std::int64_t k = 0; k < K; ++k) {
    const double hk = k + 1 == K ? h_last : h;
    // Forces at x(n) with v(n-1/2): the explicit scheme's normal law, each pair once.
    std::fill(w.fx.begin(), w.fx.end(), 0.0);
    std::fill(w.fy.begin(), w.fy.end(), 0.0);
    std::fill(w.fz.begin(), w.fz.end(), 0.0);
    auto pair = [&](std::uint32_t i, std::uint32_t j, bool own_j) {
      double dx = w.x[j] - w.x[i], dy = w.y[j] - w.y[i], dz = w.z[j] - w.z[i];
      if (own_j) dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
      const double r2 = dx * dx + dy * dy + dz * dz;
      const double rs = w.r[i] + w.r[j];
      if (r2 >= rs * rs) return;
      const double dist = std::sqrt(r2);
      const double inv = 1.0 / dist;
      const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
      const double delta = rs - dist;
      const double vn = (w.vx[i] - w.vx[j]) * nx + (w.vy[i] - w.vy[j]) * ny +
                        (w.vz[i] - w.vz[j]) * nz;
      const double meff = w.m[i] * w.m[j] / (w.m[i] + w.m[j]);
      const double fn = normal_force(m.pair, meff, delta, vn);
      w.fx[i] -= fn * nx, w.fy[i] -= fn * ny, w.fz[i] -= fn * nz;
      if (own_j) w.fx[j] += fn * nx, w.fy[j] += fn * ny, w.fz[j] += fn * nz;
      const double ratio = delta / std::min(w.r[i], w.r[j]);
      w.max_ratio = std::max(w.max_ratio, ratio);
      if (ratio > lim) ++w.violations;
    };
    for (std::size_t q = 0; q < w.oi.size(); ++q) pair(w.oi[q], w.oj[q], true);
    for (std::size_t q = 0; q < w.gi.size(); ++q) pair(w.gi[q], w.gj[q], false);
    w.pair_evals += static_cast<std::int64_t>(w.oi.size() + w.gi.size());
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a]) continue;
      std::vector<double>& pos = a == 0 ? w.x : a == 1 ? w.y : w.z;
      std::vector<double>& vel = a == 0 ? w.vx : a == 1 ? w.vy : w.vz;
      std::vector<double>& f = a == 0 ? w.fx : a == 1 ? w.fy : w.fz;
      for (std::size_t i = 0; i < no; ++i)
        for (int side = 0; side < 2; ++side) {
          const double s = side ? 1.0 : -1.0;
          const double delta = side ? w.r[i] - (g.hi[a] - pos[i]) : w.r[i] - (pos[i] - g.lo[a]);
          if (delta <= 0.0) continue;
          f[i] -= s * normal_force(m.wall, w.m[i], delta, s * vel[i]);
          w.max_ratio = std::max(w.max_ratio, delta / w.r[i]);
          if (delta > lim * w.r[i]) ++w.violations;
        }
    }
    if (record && k == 0)
      for (std::size_t i = 0; i < no; ++i) {
        const double bx = ext ? w.gx[i] : m.gravity[0], by = ext ? w.gy[i] : m.gravity[1],
                     bz = ext ? w.gz[i] : m.gravity[2];
        w.svx[i] = w.vx[i] + (w.fx[i] * w.im[i] + bx) * w.hp[i];
        w.svy[i] = w.vy[i] + (w.fy[i] * w.im[i] + by) * w.hp[i];
        w.svz[i] = w.vz[i] + (w.fz[i] * w.im[i] + bz) * w.hp[i];
      }
    // v(n+1/2) = v(n-1/2) + a(n) (h_prev + h/2), x(n+1) = x(n) + v(n+1/2) h.
    const double half = 0.5 * hk;
    double md = 0.0;
    for (std::size_t i = 0; i < no; ++i) {
      const double s = w.hp[i] + half;
      const double bx = ext ? w.gx[i] : m.gravity[0], by = ext ? w.gy[i] : m.gravity[1],
                   bz = ext ? w.gz[i] : m.gravity[2];
      w.vx[i] += (w.fx[i] * w.im[i] + bx) * s;
      w.vy[i] += (w.fy[i] * w.im[i] + by) * s;
      w.vz[i] += (w.fz[i] * w.im[i] + bz) * s;
      w.x[i] += w.vx[i] * hk, w.y[i] += w.vy[i] * hk, w.z[i] += w.vz[i] * hk;
      w.hp[i] = half;
      const double ex = w.x[i] - w.x0[i], ey = w.y[i] - w.y0[i], ez = w.z[i] - w.z0[i];
      md = std::max(md, ex * ex + ey * ey + ez * ez);
    }
    // Ghosts do not move: own-own pairs need the skin/2 bound, own-ghost pairs tolerate skin.
    if (k + 1 < K && md > 0.25 * skin * skin) build(false);
  }
  w.steps = K;
  for (std::size_t i = 0; i < no && w.fault == Fault::none; ++i) {
    const double q[3] = {w.x[i], w.y[i], w.z[i]};
    const double v2 = w.vx[i] * w.vx[i] + w.vy[i] * w.vy[i] + w.vz[i] * w.vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2])) {
      w.fault = Fault::nan, w.fault_index = static_cast<std::uint32_t>(i), w.fault_value = v2;
      break;
    }
    for (int a = 0; a < 3; ++a)
      if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a])) {
        w.fault = Fault::left_domain, w.fault_index = static_cast<std::uint32_t>(i);
        w.fault_value = q[a];
        break;
      }
  }
}

void OrbScheme::subiterate(bool record) {
  if (subits_ % nsubit_ == 0) regrid();
  const int nl = static_cast<int>(ranges_.size()) - 1;
  const std::size_t n = p_.size();
  if (record) {
    sx_.resize(n), sy_.resize(n), sz_.resize(n), svx_.resize(n), svy_.resize(n),
        svz_.resize(n);
    smass_ = p_.mass, sid_ = p_.id, sradius_ = p_.radius;
    sleaf_.resize(n), sdt_.resize(n);
    for (int l = 0; l < nl; ++l)
      for (std::uint32_t i = ranges_[static_cast<std::size_t>(l)];
           i < ranges_[static_cast<std::size_t>(l) + 1]; ++i)
        sleaf_[i] = l;
  }
  {
    PhaseTimer::Scope t(timer_, Phase::force);
    // One leaf per task; each writes only its own workspace, then only its own particles.
    tbb::parallel_for(
        tbb::blocked_range<int>(0, nl, 1),
        [&](const tbb::blocked_range<int>& r) {
          for (int l = r.begin(); l != r.end(); ++l)
            run_leaf(l, record, work_[static_cast<std::size_t>(l)]);
        },
        tbb::simple_partitioner{});
    tbb::parallel_for(
        tbb::blocked_range<int>(0, nl, 1),
        [&](const tbb::blocked_range<int>& r) {
          for (int l = r.begin(); l != r.end(); ++l) {
            const Workspace& w = work_[static_cast<std::size_t>(l)];
            const std::uint32_t b = ranges_[static_cast<std::size_t>(l)];
            for (std::size_t i = 0; i < w.n_own; ++i) {
              const std::size_t k = b + i;
              p_.x[k] = geom_.wrap(w.x[i], 0), p_.y[k] = geom_.wrap(w.y[i], 1);
              p_.z[k] = geom_.wrap(w.z[i], 2);
              p_.vx[k] = w.vx[i], p_.vy[k] = w.vy[i], p_.vz[k] = w.vz[i];
              p_.fx[k] = w.fx[i], p_.fy[k] = w.fy[i], p_.fz[k] = w.fz[i];
              hprev_[k] = w.hp[i];
              if (record) {
                sx_[k] = w.sx[i], sy_[k] = w.sy[i], sz_[k] = w.sz[i];
                svx_[k] = w.svx[i], svy_[k] = w.svy[i], svz_[k] = w.svz[i];
              }
            }
          }
        },
        tbb::simple_partitioner{});
  }
  // Counters, reduced in leaf order.
  std::int64_t fine = 0, busy = 0;
  for (int l = 0; l < nl; ++l) {
    const Workspace& w = work_[static_cast<std::size_t>(l)];
    if (w.fault != Fault::none) {
      const std::size_t k = ranges_[static_cast<std::size_t>(l)] + w.fault_index;
      throw RunError(fmt::format(
          "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {}", time(),
          subits_, p_.id[k], p_.x[k], p_.y[k], p_.z[k],
          w.fault == Fault::nan
              ? "position or velocity is not finite (NaN/inf): the step is unstable"
              : fmt::format("left the domain through a wall (coordinate {:.6g} m)",
                            w.fault_value)));
    }
    if (w.n_own == 0) continue;
    if (record)
      for (std::uint32_t i = ranges_[static_cast<std::size_t>(l)];
           i < ranges_[static_cast<std::size_t>(l) + 1]; ++i)
        sdt_[i] = dt_sp_ / static_cast<double>(std::max<std::int64_t>(w.steps, 1));
    ++busy;
    fine += w.fine;
    leaf_steps_[static_cast<std::size_t>(l)] += w.steps;
    particle_steps_ += static_cast<std::int64_t>(w.n_own) * w.steps;
    pair_evaluations_ += w.pair_evals;
    builds_ += w.builds;
    overlap_violations_ += w.violations;
    max_overlap_ratio_ = std::max(max_overlap_ratio_, w.max_ratio);
  }
  fine_count_ += fine;
  leaf_subits_ += busy;
  last_fine_fraction_ = busy > 0 ? static_cast<double>(fine) / static_cast<double>(busy) : 0.0;
  ++subits_;
  resort();
}

LeafStepStats OrbScheme::take_interval_stats() {
  LeafStepStats s;
  std::int64_t lo = std::numeric_limits<std::int64_t>::max(), hi = 0, sum = 0, count = 0;
  for (auto& v : leaf_steps_) {
    if (v > 0) lo = std::min(lo, v), hi = std::max(hi, v), sum += v, ++count;
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

OrbScheme::State OrbScheme::save_state() const {
  if (subits_ % nsubit_ != 0)
    throw RunError("orb checkpoint requested between regrid points (internal error)");
  State s;
  s.hprev = hprev_, s.leaf_steps = leaf_steps_;
  s.fine_count = fine_count_, s.leaf_subits = leaf_subits_, s.subits = subits_;
  s.particle_steps = particle_steps_, s.pair_evaluations = pair_evaluations_, s.builds = builds_;
  s.regrids = regrids_, s.overlap_violations = overlap_violations_;
  s.last_fine_fraction = last_fine_fraction_, s.max_overlap_ratio = max_overlap_ratio_;
  return s;
}

void OrbScheme::restore_state(State s) {
  if (s.hprev.size() != p_.size() || s.subits < 0 || s.subits % nsubit_ != 0)
    throw RunError("checkpoint: the orb state does not fit the particles or dem.nsubit");
  hprev_ = std::move(s.hprev), leaf_steps_ = std::move(s.leaf_steps);
  fine_count_ = s.fine_count, leaf_subits_ = s.leaf_subits, subits_ = s.subits;
  particle_steps_ = s.particle_steps, pair_evaluations_ = s.pair_evaluations, builds_ = s.builds;
  regrids_ = s.regrids, overlap_violations_ = s.overlap_violations;
  last_fine_fraction_ = s.last_fine_fraction, max_overlap_ratio_ = s.max_overlap_ratio;
}

} // namespace cfddem::dem
