#include "dem/islands_scheme.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

namespace {

// Islands larger than this run each pass as a nested parallel_for over their members.
constexpr std::uint32_t kGiantIsland = 4096;

// |F_ext / m + g| of particle i.
template <bool External>
double external_acceleration(const ParticleStore& p, const ExternalForce& e,
                             const std::array<double, 3>& g, std::size_t i) {
  double ax = g[0], ay = g[1], az = g[2];
  if constexpr (External) {
    ax += e.x[i] * p.inv_mass[i], ay += e.y[i] * p.inv_mass[i], az += e.z[i] * p.inv_mass[i];
  }
  return std::sqrt(ax * ax + ay * ay + az * az);
}

// The free-flight kernel of IslandsScheme::free_flight_run over len particles (pointers at the
// run's first). Branch-free, so that it vectorizes: a coordinate or speed that is not finite
// makes q - q a NaN (non-zero bits), and a particle beyond a wall makes the smallest of its wall
// gaps negative (sign bit; with Walls only: on a periodic axis the bounds are infinite). Returns
// a value with the sign bit set when either happened.
template <bool External, bool Record, bool Walls>
std::uint64_t
free_flight_kernel(double* __restrict x, double* __restrict y, double* __restrict z,
                   double* __restrict vx, double* __restrict vy, double* __restrict vz,
                   double* __restrict hp, const double* __restrict im, const double* __restrict ex,
                   const double* __restrict ey, const double* __restrict ez, double* __restrict sx,
                   double* __restrict sy, double* __restrict sz, std::size_t len, const double* g,
                   double dt, const WallBounds& wb) {
  const double g0 = g[0], g1 = g[1], g2 = g[2], half = 0.5 * dt;
  const double lo0 = wb.lo[0], lo1 = wb.lo[1], lo2 = wb.lo[2];
  const double hi0 = wb.hi[0], hi1 = wb.hi[1], hi2 = wb.hi[2];
  std::uint64_t nonfinite = 0, outside = 0;
  for (std::size_t i = 0; i < len; ++i) {
    double ax = g0, ay = g1, az = g2;
    if constexpr (External) {
      ax += ex[i] * im[i], ay += ey[i] * im[i], az += ez[i] * im[i];
    }
    if constexpr (Record) {
      sx[i] = vx[i] + ax * hp[i], sy[i] = vy[i] + ay * hp[i], sz[i] = vz[i] + az * hp[i];
    }
    const double s = hp[i] + half;
    double px = x[i], py = y[i], pz = z[i], ux = vx[i], uy = vy[i], uz = vz[i];
    kick_drift(px, ux, 0.0, 0.0, ax * s, dt);
    kick_drift(py, uy, 0.0, 0.0, ay * s, dt);
    kick_drift(pz, uz, 0.0, 0.0, az * s, dt);
    x[i] = px, y[i] = py, z[i] = pz, vx[i] = ux, vy[i] = uy, vz[i] = uz;
    hp[i] = half;
    const double q = ux * ux + uy * uy + uz * uz + px + py + pz;
    nonfinite |= std::bit_cast<std::uint64_t>(q - q); // 0 when q is finite
    if constexpr (Walls) {
      // x - lo and hi - x are +0 at a wall, negative beyond it (q catches a NaN coordinate).
      const double gx = std::min(px - lo0, hi0 - px), gy = std::min(py - lo1, hi1 - py);
      const double gap = std::min(std::min(gx, gy), std::min(pz - lo2, hi2 - pz));
      outside |= std::bit_cast<std::uint64_t>(gap);
    }
  }
  return (nonfinite != 0 ? std::uint64_t{1} << 63 : 0) | (outside & (std::uint64_t{1} << 63));
}

} // namespace

IslandsScheme::IslandsScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain),
      model_(make_step_model(scene, particles)) {
  require_frictionless(model_, "islands");
  nsubit_ = scene.dem.nsubit;
  dt_sp_ = scene.dem.regrid_interval / static_cast<double>(nsubit_);
  // The list only finds links and island members (cheap per entry) while its builds are the
  // scheme's largest cost: without dem.neighbor_skin, three times the explicit scheme's skin
  // (measured on HCS 1222: 3.2x fewer builds, 30% less wall time than with the same skin).
  islands_skin_ = scene.dem.neighbor_skin > 0.0 ? model_.skin : 3.0 * model_.skin;
  global_skin_ = model_.skin;
  skin_ = islands_skin_;
  double r_max = 0.0;
  for (double r : p_.radius)
    r_max = std::max(r_max, r);
  // A link margin far above rounding and far below any gap that matters.
  margin_ = 1e-3 * model_.r_min;
  skin_cap_ = periodic_skin_cap(geom_, r_max);
  hprev_.assign(p_.size(), 0.0);
  size_hist_.assign(34, 0);
}

void IslandsScheme::start() {
  hprev_.assign(p_.size(), 0.0);
  fine_subits_.assign(p_.size(), 0);
  island_of_.assign(p_.size(), kAlone);
  busy_v_.clear();
  subits_ = 0;
  rebuild();
}

IslandsScheme::State IslandsScheme::save_state() const {
  State s;
  if (built_) {
    s.offsets.assign(list_.offsets().begin(), list_.offsets().end());
    s.neighbors.assign(list_.neighbors().begin(), list_.neighbors().end());
    s.x_ref.assign(list_.x_ref().begin(), list_.x_ref().end());
    s.y_ref.assign(list_.y_ref().begin(), list_.y_ref().end());
    s.z_ref.assign(list_.z_ref().begin(), list_.z_ref().end());
  }
  s.skin = skin_;
  s.hprev = hprev_;
  s.fine_subits = fine_subits_;
  s.size_hist = size_hist_;
  s.counters = {
      subits_,           particle_steps_, pair_evaluations_, builds_,       overlap_violations_,
      bound_violations_, global_subits_,  iv_fine_,          iv_particles_, iv_steps_,
      iv_min_,           iv_max_};
  s.max_overlap_ratio = max_overlap_ratio_;
  s.last_fine_fraction = last_fine_fraction_;
  return s;
}

void IslandsScheme::restore_state(State s) {
  const std::size_t n = p_.size();
  check_saved_list(n, s.offsets, s.neighbors, s.x_ref, s.y_ref, s.z_ref);
  // An R-rank checkpoint holds no histogram: it counts from the restart on.
  if (s.size_hist.empty())
    s.size_hist.assign(size_hist_.size(), 0);
  if (s.hprev.size() != n || s.fine_subits.size() != n || s.size_hist.size() != size_hist_.size() ||
      s.counters.size() != 12 || !(s.skin > 0.0))
    throw RunError("checkpoint: the islands scheme's state does not fit the particles");
  built_ = !s.offsets.empty();
  if (built_)
    list_.restore(std::move(s.offsets), std::move(s.neighbors), std::move(s.x_ref),
                  std::move(s.y_ref), std::move(s.z_ref), s.skin, geom_);
  skin_ = s.skin;
  hprev_ = std::move(s.hprev);
  fine_subits_ = std::move(s.fine_subits);
  size_hist_ = std::move(s.size_hist);
  const auto& k = s.counters;
  subits_ = k[0], particle_steps_ = k[1], pair_evaluations_ = k[2], builds_ = k[3];
  overlap_violations_ = k[4], bound_violations_ = k[5], global_subits_ = k[6];
  iv_fine_ = k[7], iv_particles_ = k[8], iv_steps_ = k[9], iv_min_ = k[10], iv_max_ = k[11];
  max_overlap_ratio_ = s.max_overlap_ratio;
  last_fine_fraction_ = s.last_fine_fraction;
  island_of_.assign(n, kAlone);
  busy_v_.clear();
}

void IslandsScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                       std::span<const double> fz) {
  ext_.set(fx, fy, fz, p_.size());
}

void IslandsScheme::replace_external_force(std::span<const double> fx, std::span<const double> fy,
                                           std::span<const double> fz) {
  // hprev_ was sized at construction; after a checkpoint restore it is the saved one.
  if (ext_.active() || !fx.empty())
    settle_owed_half_kick(p_.vx, p_.vy, p_.vz, p_.inv_mass,
                          std::span<const double>(hprev_).first(p_.size()), ext_.x, ext_.y, ext_.z,
                          fx, fy, fz);
  set_external_force(fx, fy, fz);
}

// The Verlet list sorts the store by cell: the per-particle state follows.
void IslandsScheme::rebuild() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  list_.build(p_, geom_, skin_);
  const auto order = list_.order();
  if (!order.empty()) {
    std::vector<double> h(order.size());
    for (std::size_t k = 0; k < order.size(); ++k)
      h[k] = hprev_[order[k]];
    hprev_.swap(h);
    std::vector<std::int64_t> f(order.size());
    for (std::size_t k = 0; k < order.size(); ++k)
      f[k] = fine_subits_[order[k]];
    fine_subits_.swap(f);
    ext_.permute(order);
  }
  built_ = true;
  ++builds_;
}

void IslandsScheme::speed_bounds() {
  const std::size_t n = p_.size();
  bound_.resize(n);
  const double* __restrict vx = p_.vx.data();
  const double* __restrict vy = p_.vy.data();
  const double* __restrict vz = p_.vz.data();
  const double* __restrict hp = hprev_.data();
  double* __restrict b = bound_.data();
  if (!ext_.active()) {
    // Gravity alone: one acceleration for all.
    const auto& g = model_.gravity;
    const double a = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    for (std::size_t i = 0; i < n; ++i)
      b[i] = std::sqrt(vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]) + a * (hp[i] + dt_sp_);
    return;
  }
  for (std::size_t i = 0; i < n; ++i)
    b[i] = std::sqrt(vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]) +
           external_acceleration<true>(p_, ext_, model_.gravity, i) * (hp[i] + dt_sp_);
}

// True when a pair missing from the list could touch within the sub-iteration: a pair outside
// the list was farther apart than r_i + r_j + skin at the build, so it needs the two particles'
// reaches (displacement since the build plus bound over the sub-iteration) to add up to the skin:
// the two largest reaches are checked against it (the list stays valid twice as long as with
// skin/2 per particle when a few particles are fast).
bool IslandsScheme::list_expires() const {
  const auto xr = list_.x_ref(), yr = list_.y_ref(), zr = list_.z_ref();
  const double* __restrict x = p_.x.data();
  const double* __restrict y = p_.y.data();
  const double* __restrict z = p_.z.data();
  const double* __restrict b = bound_.data();
  double top1 = 0.0, top2 = 0.0;
  for (std::size_t i = 0; i < p_.size(); ++i) {
    const double ex = x[i] - xr[i], ey = y[i] - yr[i], ez = z[i] - zr[i];
    const double reach = std::sqrt(ex * ex + ey * ey + ez * ez) + b[i] * dt_sp_;
    if (!(reach <= top2)) { // NaN lands here and fails below
      if (!(reach <= top1))
        top2 = top1, top1 = reach;
      else
        top2 = reach;
    }
  }
  return !(top1 + top2 < skin_);
}

// Links with the current bounds, and the islands of the linked and wall-tied particles
// (`busy_v_`, increasing); every other particle is alone (island_of_ = kAlone).
//
// The first call of a link() scans every row. Later rounds only raise bounds, and a link test
// only grows with the two bounds (floating-point addition, multiplication and comparison are
// monotone), so every link stays and a pair can become linked only if one of its particles had
// its bound raised (changed_): those rows alone are scanned, and the new links are merged into
// the list in scan order (by the pair's position in the lower particle's row, ek_), so the list
// is exactly what a full scan would give.
void IslandsScheme::make_links(bool incremental) {
  const std::size_t n = p_.size();
  const std::uint32_t* __restrict off = list_.offsets().data();
  const std::uint32_t* __restrict nb = list_.neighbors().data();
  const std::uint32_t* __restrict wrap = list_.wrap_begin().data();
  const double* __restrict x = p_.x.data();
  const double* __restrict y = p_.y.data();
  const double* __restrict z = p_.z.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict bnd = bound_.data();
  const DomainGeometry& g = geom_;
  const double dt = dt_sp_, margin = margin_;
  // The link test of pair (i, j), i < j. Pairs that do not cross a periodic face (before the
  // row's wrap_begin) need no image: image() returns their separation unchanged.
  auto linked = [&](std::uint32_t i, std::uint32_t j, bool crosses) {
    double dx = x[j] - x[i], dy = y[j] - y[i], dz = z[j] - z[i];
    if (crosses)
      dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
    const double reach = (bnd[i] + bnd[j]) * dt + margin + rad[i] + rad[j];
    return dx * dx + dy * dy + dz * dz < reach * reach;
  };
  auto tied = [&](std::uint32_t i, int a) {
    const double pos = a == 0 ? x[i] : a == 1 ? y[i] : z[i];
    const double gap = std::min(pos - g.lo[a], g.hi[a] - pos) - rad[i];
    return gap < bnd[i] * dt + margin;
  };
  if (!incremental) {
    ea_.clear(), eb_.clear(), ek_.clear();
    // Only particles with a non-empty row (increasing): most rows of a dilute scene are empty.
    for (const std::uint32_t i : list_.active()) {
      const std::uint32_t kw = wrap[i], ke = off[i + 1];
      for (std::uint32_t k = off[i]; k < ke; ++k) {
        const std::uint32_t j = nb[k];
        if (j > i && linked(i, j, k >= kw))
          ea_.push_back(i), eb_.push_back(j), ek_.push_back(k);
      }
    }
    tied_.clear();
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (std::uint32_t i = 0; i < n; ++i)
        if (tied(i, a))
          tied_.push_back(i);
    }
  } else {
    // New links from the rows of the raised particles, keyed by their position in the lower
    // particle's row; a pair both of whose particles were raised is found twice (unique).
    new_k_.clear();
    for (const std::uint32_t c : changed_)
      for (std::uint32_t k = off[c]; k < off[c + 1]; ++k) {
        const std::uint32_t j = nb[k];
        if (j > c) {
          if (linked(c, j, k >= wrap[c]))
            new_k_.push_back(k);
        } else {
          // The pair's position in row j (rows hold both directions).
          std::uint32_t kj = off[j];
          while (nb[kj] != c)
            ++kj;
          if (linked(j, c, kj >= wrap[j]))
            new_k_.push_back(kj);
        }
      }
    std::sort(new_k_.begin(), new_k_.end());
    new_k_.erase(std::unique(new_k_.begin(), new_k_.end()), new_k_.end());
    // Merge (ek_ increasing); a key already linked is kept once.
    std::size_t q = ek_.size(), r = new_k_.size();
    std::size_t added = 0;
    for (std::size_t t = 0, u = 0; u < r; ++u) {
      while (t < q && ek_[t] < new_k_[u])
        ++t;
      if (t == q || ek_[t] != new_k_[u])
        new_k_[added++] = new_k_[u];
    }
    new_k_.resize(added);
    if (added > 0) {
      ea_.resize(q + added), eb_.resize(q + added), ek_.resize(q + added);
      // Back to front: the merged list in place.
      std::size_t w = q + added;
      while (added > 0) {
        const std::uint32_t kn = new_k_[added - 1];
        if (q > 0 && ek_[q - 1] > kn) {
          --q, --w;
          ea_[w] = ea_[q], eb_[w] = eb_[q], ek_[w] = ek_[q];
        } else {
          --added, --w;
          // Owner of position kn: the last row starting at or before it.
          const auto* row = std::upper_bound(off, off + n + 1, kn) - 1;
          ea_[w] = static_cast<std::uint32_t>(row - off), eb_[w] = nb[kn], ek_[w] = kn;
        }
      }
    }
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (const std::uint32_t c : changed_)
        if (tied(c, a))
          tied_.push_back(c); // duplicates are harmless (busy_v_ is a set)
    }
  }
  // Busy vertices: endpoints and tied particles, unique (marked), increasing; islands over them.
  for (std::uint32_t v : busy_v_)
    island_of_[v] = kAlone; // reset the last sub-iteration's
  busy_v_.clear();
  mark_.resize(n, 0);
  for (const auto* list : {&ea_, &eb_, &tied_})
    for (const std::uint32_t v : *list)
      if (!mark_[v])
        mark_[v] = 1, busy_v_.push_back(v);
  for (const std::uint32_t v : busy_v_)
    mark_[v] = 0;
  if (busy_v_.size() > kGlobalFraction * static_cast<double>(n))
    return; // link() goes global
  std::sort(busy_v_.begin(), busy_v_.end());
  for (std::uint32_t k = 0; k < busy_v_.size(); ++k)
    island_of_[busy_v_[k]] = k; // local index
  la_.resize(ea_.size()), lb_.resize(eb_.size());
  for (std::size_t q = 0; q < ea_.size(); ++q)
    la_[q] = island_of_[ea_[q]], lb_[q] = island_of_[eb_[q]];
  partition::connected_components(busy_v_.size(), la_, lb_, islands_, uf_scratch_);
  for (std::uint32_t k = 0; k < busy_v_.size(); ++k)
    island_of_[busy_v_[k]] = islands_.label[k];
}

// Islands whose bounds account for the energy contacts can move inside them: link with the
// particles' own bounds, raise every member of an island to the island's s_max (from the
// members' own bounds and the springs' energy), link again, until the islands stop changing.
// Islands only merge from round to round (bounds only grow), so this ends.
void IslandsScheme::link() {
  const DomainGeometry& g = geom_;
  const std::size_t n = p_.size();
  // Own bounds are kept only for busy particles (the only ones raised), saved the first time a
  // particle is busy in this call: busy sets only grow from round to round, so bound_ still
  // holds its own bound then. A stamp per call marks the saved ones (no O(N) copy or reset).
  own_bound_.resize(n);
  own_stamp_.resize(n, 0);
  if (++stamp_ == 0)
    std::fill(own_stamp_.begin(), own_stamp_.end(), 0u), stamp_ = 1;
  const bool ext = ext_.active();
  global_ = false;
  for (int round = 0;; ++round) {
    make_links(round > 0 && incremental_links_);
    if (busy_v_.size() > kGlobalFraction * static_cast<double>(n)) {
      // A dense bed: most particles are linked, the energy bounds of a large island are loose,
      // and the islands would cost more than they save. Step everyone finely instead.
      global_ = true;
      return;
    }
    if (round > 0 && busy_v_ == busy_before_ && islands_.label == label_before_)
      break;
    for (const std::uint32_t i : busy_v_)
      if (own_stamp_[i] != stamp_)
        own_stamp_[i] = stamp_, own_bound_[i] = bound_[i];
    const std::uint32_t nc = islands_.count();
    energy_.assign(nc, 0.0);
    m_min_.assign(nc, std::numeric_limits<double>::infinity());
    a_max_.assign(nc, 0.0);
    hp_max_.assign(nc, 0.0);
    for (std::size_t q = 0; q < ea_.size(); ++q) {
      const std::uint32_t i = ea_[q], j = eb_[q];
      const double dx = g.image(p_.x[j] - p_.x[i], 0), dy = g.image(p_.y[j] - p_.y[i], 1),
                   dz = g.image(p_.z[j] - p_.z[i], 2);
      const double delta = p_.radius[i] + p_.radius[j] - std::sqrt(dx * dx + dy * dy + dz * dz);
      if (delta > 0.0)
        energy_[island_of_[i]] += 0.5 * model_.pair.k * delta * delta;
    }
    for (const std::uint32_t i : busy_v_) {
      const std::uint32_t c = island_of_[i];
      for (int a = 0; a < 3; ++a) {
        if (g.periodic[a])
          continue;
        const double pos = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
        const double delta = p_.radius[i] - std::min(pos - g.lo[a], g.hi[a] - pos);
        if (delta > 0.0)
          energy_[c] += 0.5 * model_.wall.k * delta * delta;
      }
      energy_[c] += 0.5 * p_.mass[i] * own_bound_[i] * own_bound_[i];
      m_min_[c] = std::min(m_min_[c], p_.mass[i]);
      a_max_[c] =
          std::max(a_max_[c], ext ? external_acceleration<true>(p_, ext_, model_.gravity, i)
                                  : external_acceleration<false>(p_, ext_, model_.gravity, i));
      hp_max_[c] = std::max(hp_max_[c], hprev_[i]);
    }
    changed_.clear();
    for (const std::uint32_t i : busy_v_) {
      const std::uint32_t c = island_of_[i];
      const double b = std::max(own_bound_[i], std::sqrt(2.0 * energy_[c] / m_min_[c]) +
                                                   a_max_[c] * (hp_max_[c] + dt_sp_));
      if (b != bound_[i])
        changed_.push_back(i);
      bound_[i] = b;
    }
    if (changed_.empty())
      break;
    busy_before_ = busy_v_;
    label_before_ = islands_.label;
  }
}

void IslandsScheme::subiterate(bool record) {
  if (!built_)
    rebuild();
  {
    PhaseTimer::Scope t(timer_, Phase::neighbor);
    bool fresh = false;
    for (;;) {
      speed_bounds();
      link();
      if (global_) {
        // The explicit scheme's skin: the list then holds what the explicit list holds.
        if (skin_ != global_skin_)
          skin_ = global_skin_, rebuild();
        break;
      }
      if (skin_ < islands_skin_) {
        skin_ = islands_skin_;
        rebuild();
        fresh = true;
        continue;
      }
      if (!list_expires())
        break;
      if (fresh) {
        // Even a fresh list is too short for these bounds: grow the skin (kept for the run).
        double need = 0.0;
        for (double b : bound_)
          need = std::max(need, 2.2 * b * dt_sp_);
        if (!(need < skin_cap_))
          throw RunError(fmt::format(
              "t = {:.9g} s: particles may move {:.4g} m in one sub-iteration, more than the "
              "periodic box allows for a neighbor skin ({:.4g} m): raise dem.nsubit",
              time(), 0.5 * need, skin_cap_));
        skin_ = std::max(need, 2.0 * skin_ < skin_cap_ ? 2.0 * skin_ : need);
      }
      rebuild();
      fresh = true;
    }
  }
  PhaseTimer::Scope t(timer_, Phase::force);
  const std::size_t n = p_.size();
  const FineSteps steps = fine_steps(dt_sp_, model_.dt);
  K_ = steps.K;
  h_ = steps.h;
  h_last_ = steps.h_last;
  if (global_) {
    ++global_subits_;
    if (record) {
      sx_.resize(n), sy_.resize(n), sz_.resize(n), svx_.resize(n), svy_.resize(n), svz_.resize(n);
      sdt_.resize(n), sisland_.resize(n);
      for (std::size_t i = 0; i < n; ++i) {
        sx_[i] = geom_.wrap(p_.x[i], 0), sy_[i] = geom_.wrap(p_.y[i], 1),
        sz_[i] = geom_.wrap(p_.z[i], 2);
        sisland_[i] = 0, sdt_[i] = dt_sp_ / static_cast<double>(K_);
      }
      smass_ = p_.mass, sid_ = p_.id, sradius_ = p_.radius;
    }
    for (auto& f : fine_subits_)
      ++f;
    size_hist_[static_cast<std::size_t>(std::bit_width(static_cast<std::uint64_t>(n) - 1))] += 1;
    ext_.active() ? global_steps<true>(record) : global_steps<false>(record);
    ++subits_;
    raise_faults(time());
    const auto nn = static_cast<std::int64_t>(n);
    particle_steps_ += nn * K_;
    last_fine_fraction_ = 1.0;
    iv_fine_ += nn, iv_particles_ += nn, iv_steps_ += nn * K_;
    iv_min_ = std::min(iv_min_, K_), iv_max_ = std::max(iv_max_, K_);
    return;
  }
  // Every island of busy particles (a link or a wall) takes the fine steps; the rest fly free.
  const std::uint32_t nc = islands_.count();
  for (std::uint32_t c = 0; c < nc; ++c)
    ++size_hist_[static_cast<std::size_t>(std::bit_width(islands_.size(c) - 1))];
  size_hist_[0] += static_cast<std::int64_t>(n - busy_v_.size());
  // Island members in particle order (islands_.members holds local indices).
  members_.resize(busy_v_.size());
  for (std::size_t k = 0; k < busy_v_.size(); ++k)
    members_[k] = busy_v_[islands_.members[k]];
  for (const std::uint32_t i : busy_v_)
    ++fine_subits_[i];
  if (record) {
    sx_.resize(n), sy_.resize(n), sz_.resize(n), svx_.resize(n), svy_.resize(n), svz_.resize(n);
    sdt_.resize(n), sisland_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      sx_[i] = geom_.wrap(p_.x[i], 0), sy_[i] = geom_.wrap(p_.y[i], 1),
      sz_[i] = geom_.wrap(p_.z[i], 2);
      const bool fine = island_of_[i] != kAlone;
      sisland_[i] = fine ? static_cast<std::int64_t>(island_of_[i]) : -1;
      sdt_[i] = fine ? dt_sp_ / static_cast<double>(K_) : dt_sp_;
    }
    smass_ = p_.mass, sid_ = p_.id, sradius_ = p_.radius;
  }
  // Start positions of the members (members_ order), for the bound check of their steps.
  x0_.resize(members_.size()), y0_.resize(members_.size()), z0_.resize(members_.size());
  for (std::size_t k = 0; k < members_.size(); ++k) {
    const std::uint32_t i = members_[k];
    x0_[k] = p_.x[i], y0_[k] = p_.y[i], z0_[k] = p_.z[i];
  }
  // Free flight first, then the islands' tasks (they touch disjoint particles).
  ext_.active() ? free_flight<true>(record) : free_flight<false>(record);
  results_.assign(nc, IslandResult{});
  auto islands_range = [&](std::size_t b, std::size_t e) {
    for (std::size_t q = b; q != e; ++q)
      ext_.active() ? run_island<true>(static_cast<std::uint32_t>(q), record)
                    : run_island<false>(static_cast<std::uint32_t>(q), record);
  };
  if (busy_v_.size() < 256) {
    islands_range(0, nc); // few fine particles: no task overhead
  } else {
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, nc, 1),
        [&](const tbb::blocked_range<std::size_t>& r) { islands_range(r.begin(), r.end()); });
  }
  // Counters, in island order.
  std::int64_t members = 0;
  for (std::uint32_t q = 0; q < nc; ++q) {
    const IslandResult& r = results_[q];
    members += islands_.size(q);
    pair_evaluations_ += r.pairs;
    overlap_violations_ += r.violations;
    bound_violations_ += r.bound_violations;
    max_overlap_ratio_ = std::max(max_overlap_ratio_, r.max_ratio);
  }
  ++subits_;
  // Free particles were checked in free_flight(); the islands' members are few: check them here.
  {
    const double inf = std::numeric_limits<double>::infinity();
    for (const std::uint32_t i : busy_v_) {
      const double q = p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i] + p_.x[i] +
                       p_.y[i] + p_.z[i];
      bool ok = q > -inf && q < inf;
      for (int a = 0; a < 3; ++a) {
        const double c = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
        ok = ok && (geom_.periodic[a] || (c >= geom_.lo[a] && c <= geom_.hi[a]));
      }
      if (!ok)
        fault_flag_ |= std::uint64_t{1} << 63;
    }
  }
  if (fault_flag_ >> 63) {
    raise_faults(time()); // throws with the particle named (a NaN sum can flag falsely: no)
    fault_flag_ = 0;
  }
  const std::int64_t free_count = static_cast<std::int64_t>(n) - members;
  particle_steps_ += free_count + members * K_;
  last_fine_fraction_ = n > 0 ? static_cast<double>(members) / static_cast<double>(n) : 0.0;
  iv_fine_ += members;
  iv_particles_ += static_cast<std::int64_t>(n);
  iv_steps_ += free_count + members * K_;
  iv_min_ = std::min(iv_min_, free_count > 0 ? std::int64_t{1} : K_);
  iv_max_ = std::max(iv_max_, members > 0 ? K_ : std::int64_t{1});
}

// One step of dt_sp for every particle not in a fine island: no contact can act on it. The
// busy particles (busy_v_, increasing) split the store into runs of free particles; each run
// is one branch-free loop (no per-particle island test or select: the runs hold ~99% of a
// dilute store).
template <bool External> void IslandsScheme::free_flight(bool record) {
  const std::size_t n = p_.size();
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  // Runs of free particles in [b, e): between the busy particles that fall in it.
  auto range = [&](std::size_t b, std::size_t e) {
    std::uint64_t bad = 0;
    auto q = std::lower_bound(busy_v_.begin(), busy_v_.end(), static_cast<std::uint32_t>(b));
    for (std::size_t i = b; i < e;) {
      const std::size_t stop = q != busy_v_.end() ? std::min<std::size_t>(e, *q) : e;
      if (stop > i)
        bad |= record  ? free_flight_run<External, true, true>(i, stop)
               : walls ? free_flight_run<External, false, true>(i, stop)
                       : free_flight_run<External, false, false>(i, stop);
      i = stop + 1; // past the busy particle (or past e)
      if (q != busy_v_.end())
        ++q;
    }
    return bad;
  };
  std::uint64_t bad = 0;
  if (n <= 4096) {
    bad = range(0, n); // small: no task overhead
  } else {
    constexpr std::size_t kBlock = 2048;
    std::vector<std::uint64_t> flags((n + kBlock - 1) / kBlock, 0);
    tbb::parallel_for(std::size_t{0}, flags.size(), [&](std::size_t k) {
      flags[k] = range(k * kBlock, std::min(n, (k + 1) * kBlock));
    });
    for (std::uint64_t f : flags)
      bad |= f;
  }
  fault_flag_ |= bad;
}

// Free flight of particles [b, e), all alone: the explicit scheme's kick-drift with no contact
// force (contact_kernels.hpp). Faults (NaN, or a particle outside a wall) are flagged in the
// same pass (sign bit of the result); raise_faults() names the particle only when one is flagged.
template <bool External, bool Record, bool Walls>
std::uint64_t IslandsScheme::free_flight_run(std::size_t b, std::size_t e) {
  const WallBounds wb(geom_);
  return free_flight_kernel<External, Record, Walls>(
      p_.x.data() + b, p_.y.data() + b, p_.z.data() + b, p_.vx.data() + b, p_.vy.data() + b,
      p_.vz.data() + b, hprev_.data() + b, p_.inv_mass.data() + b,
      External ? ext_.x.data() + b : nullptr, External ? ext_.y.data() + b : nullptr,
      External ? ext_.z.data() + b : nullptr, Record ? svx_.data() + b : nullptr,
      Record ? svy_.data() + b : nullptr, Record ? svz_.data() + b : nullptr, e - b,
      model_.gravity.data(), dt_sp_, wb);
}

// Contact and wall forces on particles u0..u1 (idx[u] with Indexed, else u itself; the explicit
// scheme's contact law), from their list partners in island c (with Label; all partners
// without). Returns the pairs (i, j > i) evaluated.
template <bool Label, bool Indexed>
std::int64_t IslandsScheme::particle_forces(const std::uint32_t* idx, std::uint32_t u0,
                                            std::uint32_t u1, std::uint32_t c,
                                            double& max_ratio_out, std::int64_t& violations_out) {
  const std::uint32_t* __restrict off = list_.offsets().data();
  const std::uint32_t* __restrict nb = list_.neighbors().data();
  const std::uint32_t* __restrict wrap = list_.wrap_begin().data();
  const std::uint32_t* __restrict label = island_of_.data();
  // References (a copy per particle would cost more than it saves): the loop stores only to
  // locals, so their fields stay in registers.
  const DomainGeometry& g = geom_;
  const StepModel& m = model_;
  const double* __restrict x = p_.x.data();
  const double* __restrict y = p_.y.data();
  const double* __restrict z = p_.z.data();
  const double* __restrict vx = p_.vx.data();
  const double* __restrict vy = p_.vy.data();
  const double* __restrict vz = p_.vz.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict mass = p_.mass.data();
  double* __restrict fxo = p_.fx.data();
  double* __restrict fyo = p_.fy.data();
  double* __restrict fzo = p_.fz.data();
  double max_ratio = max_ratio_out;
  std::int64_t pairs = 0, violations = 0;
  for (std::uint32_t u = u0; u < u1; ++u) {
    const std::uint32_t i = Indexed ? idx[u] : u;
    const double xi = x[i], yi = y[i], zi = z[i], vxi = vx[i], vyi = vy[i], vzi = vz[i];
    const double ri = rad[i], mi = mass[i];
    double ax = 0.0, ay = 0.0, az = 0.0;
    auto pair = [&](std::uint32_t j, double dx, double dy, double dz) {
      const double delta = add_normal_contact(m, dx, dy, dz, ri, rad[j], mi, mass[j], vxi - vx[j],
                                              vyi - vy[j], vzi - vz[j], ax, ay, az);
      if (delta <= 0.0)
        return;
      // The ratio's divide only when it sets a new maximum (rare after the first contacts).
      const double rmin = std::min(ri, rad[j]);
      if (delta > max_ratio * rmin)
        max_ratio = delta / rmin;
      violations += delta > m.max_overlap * rmin;
    };
    // Pairs inside the box first (no periodic image needed), then those across a face.
    const std::uint32_t kw = wrap[i];
    for (std::uint32_t k = off[i]; k < kw; ++k) {
      const std::uint32_t j = nb[k];
      if constexpr (Label) {
        if (label[j] != c)
          continue;
      }
      pairs += j > i;
      pair(j, x[j] - xi, y[j] - yi, z[j] - zi);
    }
    for (std::uint32_t k = kw; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      if constexpr (Label) {
        if (label[j] != c)
          continue;
      }
      pairs += j > i;
      pair(j, g.image(x[j] - xi, 0), g.image(y[j] - yi, 1), g.image(z[j] - zi, 2));
    }
    if (!(g.periodic[0] && g.periodic[1] && g.periodic[2])) {
      double f[3] = {ax, ay, az};
      const double pos[3] = {xi, yi, zi}, vel[3] = {vxi, vyi, vzi};
      for (int a = 0; a < 3; ++a) {
        if (g.periodic[a])
          continue;
        for (int side = 0; side < 2; ++side) {
          const double sg = side ? 1.0 : -1.0;
          const double delta = side ? ri - (g.hi[a] - pos[a]) : ri - (pos[a] - g.lo[a]);
          if (delta <= 0.0)
            continue;
          f[a] -= sg * normal_force(m.wall, mi, delta, sg * vel[a]);
          max_ratio = std::max(max_ratio, delta / ri);
          violations += delta > m.max_overlap * ri;
        }
      }
      ax = f[0], ay = f[1], az = f[2];
    }
    fxo[i] = ax, fyo[i] = ay, fzo[i] = az;
  }
  max_ratio_out = max_ratio;
  violations_out += violations;
  return pairs;
}

// A sub-iteration where a large part of the particles is linked (a dense bed): every particle
// takes the K fine steps together, as the explicit scheme would, all partners read live (no
// bound is needed: nothing flies free). The list is checked after every step, as the explicit
// scheme checks it, and rebuilt when some particle moved more than skin/2.
template <bool External> void IslandsScheme::global_steps(bool record) {
  const std::size_t n = p_.size();
  const StepModel& m = model_;
  constexpr std::size_t kBlock = 1024;
  const std::size_t blocks = (n + kBlock - 1) / kBlock;
  struct Part {
    std::int64_t pairs = 0, violations = 0;
    double max_ratio = 0.0;
    std::uint64_t moved = 0;
  };
  std::vector<Part> parts(blocks);
  double h_before = 0.0;
  for (std::int64_t k = 0; k < K_; ++k) {
    const double hk = k + 1 == K_ ? h_last_ : h_;
    if (k > 0) {
      std::uint64_t moved = 0;
      for (const Part& pt : parts)
        moved |= pt.moved;
      if (moved >> 63)
        rebuild();
    }
    tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
      Part pt;
      const std::size_t e = std::min(n, (b + 1) * kBlock);
      pt.pairs += particle_forces<false, false>(nullptr, static_cast<std::uint32_t>(b * kBlock),
                                                static_cast<std::uint32_t>(e), 0, pt.max_ratio,
                                                pt.violations);
      parts[b] = pt;
    });
    if (record && k == 0)
      for (std::size_t i = 0; i < n; ++i) {
        double ex = 0.0, ey = 0.0, ez = 0.0;
        if constexpr (External)
          ex = ext_.x[i], ey = ext_.y[i], ez = ext_.z[i];
        svx_[i] = p_.vx[i] + ((p_.fx[i] + ex) * p_.inv_mass[i] + m.gravity[0]) * hprev_[i];
        svy_[i] = p_.vy[i] + ((p_.fy[i] + ey) * p_.inv_mass[i] + m.gravity[1]) * hprev_[i];
        svz_[i] = p_.vz[i] + ((p_.fz[i] + ez) * p_.inv_mass[i] + m.gravity[2]) * hprev_[i];
      }
    for (const Part& pt : parts) {
      pair_evaluations_ += pt.pairs;
      overlap_violations_ += pt.violations;
      max_overlap_ratio_ = std::max(max_overlap_ratio_, pt.max_ratio);
    }
    const double half = 0.5 * hk;
    const double s_common = 0.5 * h_before + half;
    const auto xr = list_.x_ref(), yr = list_.y_ref(), zr = list_.z_ref();
    const double half_skin2 = 0.25 * skin_ * skin_;
    const KickDriftColumns columns =
        kick_drift_columns(p_, xr, yr, zr, External ? &ext_ : nullptr, hprev_);
    KickDriftStep st;
    st.s = s_common, st.h = hk, st.g = m.gravity, st.half_skin2 = half_skin2;
    tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
      const std::size_t i0 = b * kBlock, i1 = std::min(n, (b + 1) * kBlock);
      KickDriftFlags flags;
      if (k == 0) // each particle's own first kick h_prev + h/2 (st.s unused)
        kick_drift_range<External, true>(columns.range(i0, i1), st, flags);
      else
        kick_drift_range<External>(columns.range(i0, i1), st, flags);
      const std::uint64_t still = flags.still;
      parts[b].moved = ~still; // sign bit set: some particle beyond skin/2
    });
    // The orb kernel leaves h_prev alone after the first step: the last step's half step.
    if (k > 0 && k + 1 == K_)
      for (double& h : hprev_)
        h = half;
    h_before = hk;
  }
}

// The K fine steps of island c (every island has a link or a wall): contact forces from members
// only (no other particle can reach them within dt_sp), walls, and the variable-step leapfrog.
template <bool External> void IslandsScheme::run_island(std::uint32_t c, bool record) {
  IslandResult res;
  const std::uint32_t* mem = members_.data() + islands_.first[c];
  const std::uint32_t count = islands_.size(c);
  const StepModel& m = model_;
  double* x = p_.x.data();
  double* y = p_.y.data();
  double* z = p_.z.data();
  double* vx = p_.vx.data();
  double* vy = p_.vy.data();
  double* vz = p_.vz.data();
  double* fx = p_.fx.data();
  double* fy = p_.fy.data();
  double* fz = p_.fz.data();
  double* hp = hprev_.data();
  const double* im = p_.inv_mass.data();
  // Member u's update over one step. Everything it reads besides the particle's own state is
  // held in locals (the stores through x, v, hp could alias members of *this otherwise, and
  // the compiler would reload them for every member).
  const double* __restrict x0 = x0_.data() + islands_.first[c];
  const double* __restrict y0 = y0_.data() + islands_.first[c];
  const double* __restrict z0 = z0_.data() + islands_.first[c];
  const double* __restrict bnd = bound_.data();
  const double* __restrict ex_x = External ? ext_.x.data() : nullptr;
  const double* __restrict ex_y = External ? ext_.y.data() : nullptr;
  const double* __restrict ex_z = External ? ext_.z.data() : nullptr;
  const double g0 = m.gravity[0], g1 = m.gravity[1], g2 = m.gravity[2], margin = margin_;
  auto kick = [=](std::uint32_t u, double s, double hk, double half, double elapsed,
                  std::int64_t& bound_violations) {
    const std::uint32_t i = mem[u];
    double ex = 0.0, ey = 0.0, ez = 0.0;
    if constexpr (External)
      ex = ex_x[i], ey = ex_y[i], ez = ex_z[i];
    const double ims = im[i] * s;
    double px = x[i], py = y[i], pz = z[i], ux = vx[i], uy = vy[i], uz = vz[i];
    kick_drift(px, ux, fx[i] + ex, ims, g0 * s, hk);
    kick_drift(py, uy, fy[i] + ey, ims, g1 * s, hk);
    kick_drift(pz, uz, fz[i] + ez, ims, g2 * s, hk);
    x[i] = px, y[i] = py, z[i] = pz, vx[i] = ux, vy[i] = uy, vz[i] = uz;
    hp[i] = half;
    const double dx = px - x0[u], dy = py - y0[u], dz = pz - z0[u];
    const double reach = bnd[i] * elapsed + margin;
    bound_violations += dx * dx + dy * dy + dz * dz > reach * reach;
  };
  const bool giant = count > kGiantIsland;
  // A giant island's passes run as nested parallel loops over blocks of members; each block's
  // partial counts go here (one allocation per sub-iteration, not per step).
  struct Part {
    std::int64_t pairs = 0, violations = 0, bound_violations = 0;
    double max_ratio = 0.0;
  };
  std::vector<Part> parts(giant ? (count + 1023) / 1024 : 0);
  auto block_end = [&](std::size_t b) {
    return std::min<std::uint32_t>(count, static_cast<std::uint32_t>((b + 1) * 1024));
  };
  double h_before = 0.0, elapsed = 0.0;
  for (std::int64_t k = 0; k < K_; ++k) {
    const double hk = k + 1 == K_ ? h_last_ : h_;
    if (!giant) {
      res.pairs += particle_forces<true, true>(mem, 0, count, c, res.max_ratio, res.violations);
    } else {
      // Each member's force and update depend only on the state before the pass:
      // thread-count independent.
      tbb::parallel_for(std::size_t{0}, parts.size(), [&](std::size_t b) {
        Part& pt = parts[b];
        pt = Part{};
        pt.pairs = particle_forces<true, true>(mem, static_cast<std::uint32_t>(b * 1024),
                                               block_end(b), c, pt.max_ratio, pt.violations);
      });
      for (const Part& pt : parts)
        res.pairs += pt.pairs, res.violations += pt.violations,
            res.max_ratio = std::max(res.max_ratio, pt.max_ratio);
    }
    if (record && k == 0)
      for (std::uint32_t u = 0; u < count; ++u) {
        const std::uint32_t i = mem[u];
        double ex = 0.0, ey = 0.0, ez = 0.0;
        if constexpr (External)
          ex = ext_.x[i], ey = ext_.y[i], ez = ext_.z[i];
        svx_[i] = vx[i] + ((fx[i] + ex) * im[i] + m.gravity[0]) * hp[i];
        svy_[i] = vy[i] + ((fy[i] + ey) * im[i] + m.gravity[1]) * hp[i];
        svz_[i] = vz[i] + ((fz[i] + ez) * im[i] + m.gravity[2]) * hp[i];
      }
    const double half = 0.5 * hk;
    elapsed += hk;
    if (!giant) {
      for (std::uint32_t u = 0; u < count; ++u) {
        kick(u, k == 0 ? hp[mem[u]] + half : 0.5 * h_before + half, hk, half, elapsed,
             res.bound_violations);
      }
    } else {
      tbb::parallel_for(std::size_t{0}, parts.size(), [&](std::size_t b) {
        std::int64_t& bv = parts[b].bound_violations;
        bv = 0;
        for (std::uint32_t u = static_cast<std::uint32_t>(b * 1024); u < block_end(b); ++u) {
          kick(u, k == 0 ? hp[mem[u]] + half : 0.5 * h_before + half, hk, half, elapsed, bv);
        }
      });
      for (const Part& pt : parts)
        res.bound_violations += pt.bound_violations;
    }
    h_before = hk;
  }
  results_[c] = res;
}

// NaN anywhere, or a particle outside a wall: stop with the particle named.
void IslandsScheme::raise_faults(double t) const {
  const DomainGeometry& g = geom_;
  {
    // Faults are rare: a branch-free pass (it vectorizes) says whether to look for one.
    const WallBounds wb(g);
    const double(&lo)[3] = wb.lo;
    const double(&hi)[3] = wb.hi;
    const double inf = std::numeric_limits<double>::infinity();
    const double* __restrict x = p_.x.data();
    const double* __restrict y = p_.y.data();
    const double* __restrict z = p_.z.data();
    const double* __restrict vx = p_.vx.data();
    const double* __restrict vy = p_.vy.data();
    const double* __restrict vz = p_.vz.data();
    std::uint64_t bad = 0;
    for (std::size_t i = 0; i < p_.size(); ++i) {
      const double q = vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i] + x[i] + y[i] + z[i];
      bad |= sign_unless(q > -inf) | sign_unless(q < inf) | sign_unless(x[i] >= lo[0]) |
             sign_unless(x[i] <= hi[0]) | sign_unless(y[i] >= lo[1]) | sign_unless(y[i] <= hi[1]) |
             sign_unless(z[i] >= lo[2]) | sign_unless(z[i] <= hi[2]);
    }
    if (!(bad >> 63))
      return;
  }
  for (std::size_t i = 0; i < p_.size(); ++i) {
    const double q[3] = {p_.x[i], p_.y[i], p_.z[i]};
    const double v2 = p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i];
    if (!std::isfinite(v2 + q[0] + q[1] + q[2]))
      throw RunError(fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: "
                                 "position or velocity is not finite (NaN/inf): the step is "
                                 "unstable",
                                 t, p_.id[i], q[0], q[1], q[2]));
    for (int a = 0; a < 3; ++a)
      if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a]))
        throw RunError(fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m left "
                                   "the domain through a wall",
                                   t, p_.id[i], q[0], q[1], q[2]));
  }
}

LeafStepStats IslandsScheme::take_interval_stats() {
  LeafStepStats s;
  if (iv_particles_ > 0) {
    s.steps_min = static_cast<double>(iv_min_);
    s.steps_max = static_cast<double>(iv_max_);
    s.steps_mean = static_cast<double>(iv_steps_) / static_cast<double>(iv_particles_);
    s.fine_fraction = static_cast<double>(iv_fine_) / static_cast<double>(iv_particles_);
  }
  iv_fine_ = iv_particles_ = iv_steps_ = 0;
  iv_min_ = std::numeric_limits<std::int64_t>::max();
  iv_max_ = 0;
  return s;
}

std::array<double, 7> IslandsScheme::fine_fraction_distribution() const {
  std::array<double, 7> d{};
  if (subits_ == 0 || fine_subits_.empty())
    return d;
  std::vector<double> f(fine_subits_.size());
  double sum = 0.0;
  for (std::size_t i = 0; i < f.size(); ++i)
    f[i] = static_cast<double>(fine_subits_[i]) / static_cast<double>(subits_), sum += f[i];
  std::sort(f.begin(), f.end());
  auto rank = [&](double q) {
    const auto k = static_cast<std::size_t>(std::ceil(q * static_cast<double>(f.size())));
    return f[std::min(f.size() - 1, k > 0 ? k - 1 : 0)];
  };
  d = {sum / static_cast<double>(f.size()),
       f.front(),
       rank(0.1),
       rank(0.5),
       rank(0.9),
       rank(0.99),
       f.back()};
  return d;
}

} // namespace cfddem::dem
