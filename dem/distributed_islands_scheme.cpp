#include "dem/distributed_islands_scheme.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>
#include <string>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/scheme_support.hpp"

namespace cfddem::dem {

namespace {
int ceil_log2(int n) {
  int l = 0;
  while ((1 << l) < n)
    ++l;
  return l;
}
constexpr std::size_t kBlock = 1024;
} // namespace

DistributedIslandsScheme::DistributedIslandsScheme(const Scene& scene, ParticleStore& particles,
                                                   const StepModel& model, const Communicator& comm,
                                                   PhaseTimer& timer)
    : scene_(scene), p_(particles), comm_(comm), timer_(timer), geom_(scene.domain), model_(model),
      exchange_(comm) {
  require_frictionless(model_, "islands");
  domain_ = partition::Aabb{scene.domain.lo, scene.domain.hi};
  // Enough boxes that the knapsack can balance (the distributed explicit scheme's rule).
  levels_ = std::min(20, std::max(scene.partition.orb_levels, ceil_log2(comm.size()) + 2));
  for (const double r : p_.radius)
    r_max_ = std::max(r_max_, r);
  r_max_ = comm_.max(r_max_);
  n_global_ = comm_.sum(static_cast<std::int64_t>(p_.size()));
  double m = 0.0;
  for (const double v : p_.mass)
    m += v;
  std::array<double, 1> ms{m};
  comm_.sum(ms);
  mass_global_ = ms[0];
  nsubit_ = scene.dem.nsubit;
  dt_sp_ = scene.dem.regrid_interval / static_cast<double>(nsubit_);
  margin_ = 1e-3 * model_.r_min; // IslandsScheme's link margin
  base_skin_ = scene.dem.neighbor_skin > 0.0 ? model_.skin : 3.0 * model_.skin;
  owned_ = p_.size();
  hprev_.assign(owned_, 0.0);
  fine_.assign(owned_, 0.0);
}

void DistributedIslandsScheme::start() {
  hprev_.assign(owned_, 0.0);
  fine_.assign(owned_, 0.0);
  subits_ = 0;
}

void DistributedIslandsScheme::set_external_force(std::span<const double> fx,
                                                  std::span<const double> fy,
                                                  std::span<const double> fz) {
  const bool on = comm_.max(fx.empty() ? 0.0 : 1.0) > 0.0;
  const bool fits = on ? fx.size() == owned_ && fy.size() == owned_ && fz.size() == owned_
                       : fy.empty() && fz.empty();
  if (comm_.max(fits ? 0.0 : 1.0) > 0.0)
    throw std::invalid_argument("set_external_force: one value per owned particle expected");
  ext_on_ = on;
  ex_.assign(fx.begin(), fx.end()), ey_.assign(fy.begin(), fy.end());
  ez_.assign(fz.begin(), fz.end());
}

void DistributedIslandsScheme::replace_external_force(std::span<const double> fx,
                                                      std::span<const double> fy,
                                                      std::span<const double> fz) {
  if (fx.size() == owned_ && hprev_.size() >= owned_)
    settle_owed_half_kick(std::span<double>(p_.vx).first(owned_),
                          std::span<double>(p_.vy).first(owned_),
                          std::span<double>(p_.vz).first(owned_), p_.inv_mass,
                          std::span<const double>(hprev_).first(owned_), ex_, ey_, ez_, fx, fy, fz);
  set_external_force(fx, fy, fz); // checks the sizes on every rank
}

void DistributedIslandsScheme::regrid() {
  for (std::size_t i = 0; i < owned_; ++i)
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
  decomposition_ = partition::decompose(comm_, p_.x, p_.y, p_.z, domain_, levels_);
  imbalances_.push_back(decomposition_.imbalance);
  ++regrids_;
}

// Every owned particle to the rank owning its wrapped position, then the owned ones in id order
// (an order that depends on the particles only, whatever the arrival order).
void DistributedIslandsScheme::migrate() {
  std::vector<int> dest(owned_);
  std::string outside;
  std::int64_t key = std::numeric_limits<std::int64_t>::max();
  for (std::size_t i = 0; i < owned_; ++i) {
    p_.x[i] = geom_.wrap(p_.x[i], 0), p_.y[i] = geom_.wrap(p_.y[i], 1),
    p_.z[i] = geom_.wrap(p_.z[i], 2);
    dest[i] = decomposition_.owner_of(p_.x[i], p_.y[i], p_.z[i]);
    if (dest[i] < 0 && p_.id[i] < key) {
      key = p_.id[i];
      outside = fmt::format("t = {:.9g} s: particle {} at ({:.6g}, {:.6g}, {:.6g}) m is outside "
                            "the domain (rank {})",
                            time(), p_.id[i], p_.x[i], p_.y[i], p_.z[i], comm_.rank());
    }
  }
  if (const std::string e = comm_.agree_on_error(key, outside); !e.empty())
    throw RunError(e);
  std::vector<std::vector<double>*> cols{&hprev_, &fine_};
  if (ext_on_)
    cols.insert(cols.end(), {&ex_, &ey_, &ez_});
  exchange_.migrate(p_, dest, cols);
  owned_ = p_.size();
  std::vector<std::uint32_t> order(owned_);
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return p_.id[a] < p_.id[b]; });
  p_.permute(order);
  for (std::vector<double>* c : cols) {
    std::vector<double> t(owned_);
    for (std::size_t k = 0; k < owned_; ++k)
      t[k] = (*c)[order[k]];
    c->swap(t);
  }
}

// IslandsScheme's own bound s_i = |v_i| + |F_ext,i / m_i + g| (h_prev,i + dt_sp), owned only.
void DistributedIslandsScheme::own_bounds() {
  bound_.resize(owned_);
  const auto& g = model_.gravity;
  for (std::size_t i = 0; i < owned_; ++i) {
    double ax = g[0], ay = g[1], az = g[2];
    if (ext_on_) {
      ax += ex_[i] * p_.inv_mass[i], ay += ey_[i] * p_.inv_mass[i], az += ez_[i] * p_.inv_mass[i];
    }
    bound_[i] = std::sqrt(p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i]) +
                std::sqrt(ax * ax + ay * ay + az * az) * (hprev_[i] + dt_sp_);
  }
}

// Ghosts within the halo 2 r_max + skin_ of this rank's boxes, their bounds, and the rows
// (step 2 of the header).
void DistributedIslandsScheme::build_ghosts_and_rows() {
  const double cutoff = 2.0 * r_max_ + skin_;
  for (int a = 0; a < 3; ++a)
    if (geom_.periodic[a] && 2.0 * cutoff >= geom_.length[a])
      throw RunError(fmt::format("t = {:.9g} s: periodic axis {} is {:.4g} m long, not more than "
                                 "twice the distributed islands scheme's halo {:.4g} m: raise "
                                 "dem.nsubit or run on one rank",
                                 time(), a, geom_.length[a], cutoff));
  const partition::OrbTree& tree = decomposition_.tree;
  const int me = comm_.rank();
  std::vector<ParticleExchange::Copy> copies;
  std::vector<int> ranks;
  for (std::size_t i = 0; i < owned_; ++i) {
    const partition::Aabb q{{p_.x[i] - cutoff, p_.y[i] - cutoff, p_.z[i] - cutoff},
                            {p_.x[i] + cutoff, p_.y[i] + cutoff, p_.z[i] + cutoff}};
    // A halo strictly inside the particle's own box reaches no other rank.
    const int own = tree.locate(p_.x[i], p_.y[i], p_.z[i]);
    if (own >= 0) {
      const partition::Aabb& b = tree.leaves()[static_cast<std::size_t>(own)].box;
      bool inside = true;
      for (int a = 0; a < 3; ++a)
        inside = inside && q.lo[a] > b.lo[a] && q.hi[a] < b.hi[a];
      if (inside)
        continue;
    }
    ranks.clear();
    for (const partition::LeafImage& li : tree.leaf_images_overlapping(q, geom_.periodic)) {
      const int r = decomposition_.owner[static_cast<std::size_t>(li.leaf)];
      if (r == me || std::find(ranks.begin(), ranks.end(), r) != ranks.end())
        continue;
      ranks.push_back(r);
    }
    // Unshifted: separations take the minimum image, as IslandsScheme's.
    for (const int r : ranks)
      copies.push_back({r, static_cast<std::uint32_t>(i), {}});
  }
  exchange_.build_ghosts(p_, owned_, std::move(copies));
  const std::size_t n = p_.size();
  bound_.resize(n);
  std::vector<double>* col[] = {&bound_};
  exchange_.forward_columns(col);
  leaf0_.assign(owned_, 0);
  rows_.build({geom_,
               {p_.x.data(), n},
               {p_.y.data(), n},
               {p_.z.data(), n},
               {p_.radius.data(), n},
               {p_.id.data(), n},
               {bound_.data(), n},
               {leaf0_.data(), owned_},
               owned_,
               cutoff,
               skin_,
               0.0,
               dt_sp_,
               false});
  x_ref_.assign(p_.x.begin(), p_.x.begin() + static_cast<std::ptrdiff_t>(owned_));
  y_ref_.assign(p_.y.begin(), p_.y.begin() + static_cast<std::ptrdiff_t>(owned_));
  z_ref_.assign(p_.z.begin(), p_.z.begin() + static_cast<std::ptrdiff_t>(owned_));
  ++builds_;
}

// IslandsScheme::make_links over pairs with an owned end (each owned pair once), walls of owned
// particles; islands over the linked and tied particles (owned and ghosts).
void DistributedIslandsScheme::make_links() {
  const auto off = rows_.off();
  const auto nb = rows_.nb();
  const DomainGeometry& g = geom_;
  ea_.clear(), eb_.clear();
  for (std::uint32_t i = 0; i < owned_; ++i)
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      if (j < owned_ && j <= i)
        continue;
      const double dx = g.image(p_.x[j] - p_.x[i], 0), dy = g.image(p_.y[j] - p_.y[i], 1),
                   dz = g.image(p_.z[j] - p_.z[i], 2);
      const double reach = (bound_[i] + bound_[j]) * dt_sp_ + margin_ + p_.radius[i] + p_.radius[j];
      if (dx * dx + dy * dy + dz * dz < reach * reach)
        ea_.push_back(i), eb_.push_back(j);
    }
  tied_.clear();
  for (int a = 0; a < 3; ++a) {
    if (g.periodic[a])
      continue;
    const std::vector<double>& pos = a == 0 ? p_.x : a == 1 ? p_.y : p_.z;
    for (std::uint32_t i = 0; i < owned_; ++i) {
      const double gap = std::min(pos[i] - g.lo[a], g.hi[a] - pos[i]) - p_.radius[i];
      if (gap < bound_[i] * dt_sp_ + margin_)
        tied_.push_back(i);
    }
  }
  for (const std::uint32_t v : busy_v_)
    island_of_[v] = kAlone;
  busy_v_.clear();
  for (const auto* list : {&ea_, &eb_, &tied_})
    for (const std::uint32_t v : *list)
      if (!mark_[v])
        mark_[v] = 1, busy_v_.push_back(v);
  for (const std::uint32_t v : busy_v_)
    mark_[v] = 0;
  std::sort(busy_v_.begin(), busy_v_.end());
  for (std::uint32_t k = 0; k < busy_v_.size(); ++k)
    island_of_[busy_v_[k]] = k;
  la_.resize(ea_.size()), lb_.resize(eb_.size());
  for (std::size_t q = 0; q < ea_.size(); ++q)
    la_[q] = island_of_[ea_[q]], lb_[q] = island_of_[eb_[q]];
  partition::connected_components(busy_v_.size(), la_, lb_, islands_, uf_scratch_);
  for (std::uint32_t k = 0; k < busy_v_.size(); ++k)
    island_of_[busy_v_[k]] = islands_.label[k];
  spans_.assign(islands_.count(), 0);
  for (const std::uint32_t v : busy_v_)
    if (v >= owned_)
      spans_[island_of_[v]] = 1;
}

double DistributedIslandsScheme::link_rounds() {
  const DomainGeometry& g = geom_;
  own_bound_ = bound_; // owned and ghosts: the owners' own bounds
  global_ = false;
  const auto& grav = model_.gravity;
  auto accel = [&](std::size_t i) {
    double ax = grav[0], ay = grav[1], az = grav[2];
    if (ext_on_) {
      ax += ex_[i] * p_.inv_mass[i], ay += ey_[i] * p_.inv_mass[i], az += ez_[i] * p_.inv_mass[i];
    }
    return std::sqrt(ax * ax + ay * ay + az * az);
  };
  for (int round = 0;; ++round) {
    make_links();
    const bool changed = round == 0 || busy_v_ != busy_before_ || islands_.label != label_before_;
    const std::uint32_t nc = islands_.count();
    energy_.assign(nc, 0.0);
    m_min_.assign(nc, std::numeric_limits<double>::infinity());
    a_max_.assign(nc, 0.0);
    hp_max_.assign(nc, 0.0);
    // Spanning islands: one set of sums for all of them, over all ranks. A pair with a ghost end
    // is counted on both ranks (more energy: still conservative).
    double e_span = 0.0, m_span = std::numeric_limits<double>::infinity(), a_span = 0.0,
           hp_span = 0.0, busy_owned = 0.0, b_max = 0.0, bound_max = 0.0;
    for (std::size_t q = 0; q < ea_.size(); ++q) {
      const std::uint32_t i = ea_[q], j = eb_[q];
      const double dx = g.image(p_.x[j] - p_.x[i], 0), dy = g.image(p_.y[j] - p_.y[i], 1),
                   dz = g.image(p_.z[j] - p_.z[i], 2);
      const double delta = p_.radius[i] + p_.radius[j] - std::sqrt(dx * dx + dy * dy + dz * dz);
      if (delta <= 0.0)
        continue;
      const std::uint32_t c = island_of_[i];
      (spans_[c] ? e_span : energy_[c]) += 0.5 * model_.pair.k * delta * delta;
    }
    for (const std::uint32_t i : busy_v_) {
      if (i >= owned_)
        break; // busy_v_ is increasing: the ghosts come last
      busy_owned += 1.0;
      const std::uint32_t c = island_of_[i];
      double e = 0.5 * p_.mass[i] * own_bound_[i] * own_bound_[i];
      for (int a = 0; a < 3; ++a) {
        if (g.periodic[a])
          continue;
        const double pos = a == 0 ? p_.x[i] : a == 1 ? p_.y[i] : p_.z[i];
        const double delta = p_.radius[i] - std::min(pos - g.lo[a], g.hi[a] - pos);
        if (delta > 0.0)
          e += 0.5 * model_.wall.k * delta * delta;
      }
      const double acc = accel(i);
      if (spans_[c]) {
        e_span += e, m_span = std::min(m_span, p_.mass[i]);
        a_span = std::max(a_span, acc), hp_span = std::max(hp_span, hprev_[i]);
      } else {
        energy_[c] += e, m_min_[c] = std::min(m_min_[c], p_.mass[i]);
        a_max_[c] = std::max(a_max_[c], acc), hp_max_[c] = std::max(hp_max_[c], hprev_[i]);
      }
    }
    // The rows and ghosts hold every pair that can link while no two particles' reaches
    // (displacement since the build + bound over the sub-iteration) add up to the skin.
    for (std::size_t i = 0; i < owned_; ++i) {
      const double dx = p_.x[i] - x_ref_[i], dy = p_.y[i] - y_ref_[i], dz = p_.z[i] - z_ref_[i];
      const double reach = std::sqrt(dx * dx + dy * dy + dz * dz) + bound_[i] * dt_sp_;
      b_max = std::max(b_max, std::isnan(reach) ? std::numeric_limits<double>::infinity() : reach);
      bound_max = std::max(bound_max, bound_[i]);
    }
    double spanning = 0.0;
    for (const std::uint32_t i : busy_v_)
      if (i < owned_ && spans_[island_of_[i]])
        spanning += 1.0;
    std::array<double, 6> mx{changed ? 1.0 : 0.0, a_span, hp_span, -m_span, b_max, bound_max};
    std::array<double, 3> sm{e_span, busy_owned, spanning};
    comm_.sum_max(sm, mx);
    last_max_bound_ = mx[5];
    spanning_global_ = static_cast<std::int64_t>(sm[2]);
    if (sm[1] > IslandsScheme::kGlobalFraction * static_cast<double>(n_global_)) {
      global_ = true; // a dense bed: everyone takes the fine steps
      return mx[4];
    }
    if (round > 0 && mx[0] == 0.0)
      return mx[4];
    const double m_all = -mx[3];
    const double s_span =
        std::isfinite(m_all) ? std::sqrt(2.0 * sm[0] / m_all) + mx[1] * (mx[2] + dt_sp_) : 0.0;
    for (const std::uint32_t i : busy_v_) {
      if (i >= owned_)
        break;
      const std::uint32_t c = island_of_[i];
      const double s =
          spans_[c] ? s_span
                    : std::sqrt(2.0 * energy_[c] / m_min_[c]) + a_max_[c] * (hp_max_[c] + dt_sp_);
      bound_[i] = std::max(own_bound_[i], s);
    }
    std::vector<double>* col[] = {&bound_};
    exchange_.forward_columns(col); // the ghosts' raised bounds from their owners
    busy_before_ = busy_v_;
    label_before_ = islands_.label;
  }
}

// Contact and wall forces on owned particle i from its row partners (of its own island with
// `label`); IslandsScheme::particle_forces's arithmetic. Returns the pairs (i, j) with j > i
// counted once (a pair with a ghost counts on the rank with the lower id).
std::int64_t DistributedIslandsScheme::forces(std::uint32_t i, bool label, double& max_ratio,
                                              std::int64_t& violations) {
  const std::uint32_t* off = rows_.off().data();
  const std::uint32_t* nb = rows_.nb().data();
  const DomainGeometry& g = geom_;
  const StepModel& m = model_;
  const double xi = p_.x[i], yi = p_.y[i], zi = p_.z[i];
  const double vxi = p_.vx[i], vyi = p_.vy[i], vzi = p_.vz[i];
  const double ri = p_.radius[i], mi = p_.mass[i];
  const std::uint32_t c = island_of_[i];
  double ax = 0.0, ay = 0.0, az = 0.0;
  std::int64_t pairs = 0;
  for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
    const std::uint32_t j = nb[k];
    if (label && island_of_[j] != c)
      continue;
    pairs += p_.id[j] > p_.id[i];
    const double delta = add_normal_contact(
        m, g.image(p_.x[j] - xi, 0), g.image(p_.y[j] - yi, 1), g.image(p_.z[j] - zi, 2), ri,
        p_.radius[j], mi, p_.mass[j], vxi - p_.vx[j], vyi - p_.vy[j], vzi - p_.vz[j], ax, ay, az);
    if (delta <= 0.0)
      continue;
    const double rmin = std::min(ri, p_.radius[j]);
    max_ratio = std::max(max_ratio, delta / rmin);
    violations += delta > m.max_overlap * rmin;
  }
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
  p_.fx[i] = f[0], p_.fy[i] = f[1], p_.fz[i] = f[2];
  return pairs;
}

// One step of dt_sp for every owned particle in no island (IslandsScheme::free_flight).
template <bool External> void DistributedIslandsScheme::free_flight(bool record) {
  const std::array<double, 3> g = model_.gravity;
  const double half = 0.5 * dt_sp_;
  for (std::size_t i = 0; i < owned_; ++i) {
    if (island_of_[i] != kAlone)
      continue;
    double ax = g[0], ay = g[1], az = g[2];
    if constexpr (External) {
      ax += ex_[i] * p_.inv_mass[i], ay += ey_[i] * p_.inv_mass[i], az += ez_[i] * p_.inv_mass[i];
    }
    const double hp = hprev_[i];
    if (record)
      svx_[i] = p_.vx[i] + ax * hp, svy_[i] = p_.vy[i] + ay * hp, svz_[i] = p_.vz[i] + az * hp;
    const double s = hp + half;
    kick_drift(p_.x[i], p_.vx[i], 0.0, 0.0, ax * s, dt_sp_);
    kick_drift(p_.y[i], p_.vy[i], 0.0, 0.0, ay * s, dt_sp_);
    kick_drift(p_.z[i], p_.vz[i], 0.0, 0.0, az * s, dt_sp_);
    hprev_[i] = half;
  }
}

// The K fine steps of local island c (IslandsScheme::run_island, its members all owned).
template <bool External>
void DistributedIslandsScheme::run_local_island(std::uint32_t c, bool record) {
  Result res;
  const std::uint32_t* mem = members_.data() + islands_.first[c];
  const std::uint32_t count = islands_.size(c);
  const StepModel& m = model_;
  double h_before = 0.0, elapsed = 0.0;
  for (std::int64_t k = 0; k < K_; ++k) {
    const double hk = k + 1 == K_ ? h_last_ : h_;
    for (std::uint32_t u = 0; u < count; ++u)
      res.pairs += forces(mem[u], true, res.max_ratio, res.violations);
    const double half = 0.5 * hk;
    elapsed += hk;
    for (std::uint32_t u = 0; u < count; ++u) {
      const std::uint32_t i = mem[u];
      double ex = 0.0, ey = 0.0, ez = 0.0;
      if constexpr (External)
        ex = ex_[i], ey = ey_[i], ez = ez_[i];
      const double im = p_.inv_mass[i];
      if (record && k == 0) {
        svx_[i] = p_.vx[i] + ((p_.fx[i] + ex) * im + m.gravity[0]) * hprev_[i];
        svy_[i] = p_.vy[i] + ((p_.fy[i] + ey) * im + m.gravity[1]) * hprev_[i];
        svz_[i] = p_.vz[i] + ((p_.fz[i] + ez) * im + m.gravity[2]) * hprev_[i];
      }
      const double s = k == 0 ? hprev_[i] + half : 0.5 * h_before + half;
      const double ims = im * s;
      kick_drift(p_.x[i], p_.vx[i], p_.fx[i] + ex, ims, m.gravity[0] * s, hk);
      kick_drift(p_.y[i], p_.vy[i], p_.fy[i] + ey, ims, m.gravity[1] * s, hk);
      kick_drift(p_.z[i], p_.vz[i], p_.fz[i] + ez, ims, m.gravity[2] * s, hk);
      hprev_[i] = half;
      const double dx = p_.x[i] - x0_[i], dy = p_.y[i] - y0_[i], dz = p_.z[i] - z0_[i];
      const double reach = bound_[i] * elapsed + margin_;
      res.bound_violations += dx * dx + dy * dy + dz * dz > reach * reach;
    }
    h_before = hk;
  }
  results_[c] = res;
}

// The K fine steps of every spanning member (all: every owned particle, the dense mode), all
// ranks together: forces, kick-drift, then the ghosts' x and v from their owners after every
// step (collective, also on a rank with no member). Each member's force and update read only
// the state before the pass: bitwise independent of the thread count.
template <bool External> void DistributedIslandsScheme::fine_together(bool record, bool all) {
  if (all) {
    span_members_.resize(owned_);
    std::iota(span_members_.begin(), span_members_.end(), 0U);
  }
  const std::size_t count = span_members_.size();
  const std::size_t blocks = (count + kBlock - 1) / kBlock;
  std::vector<Result> parts(blocks);
  const StepModel& m = model_;
  const double half_skin2 = 0.25 * skin_ * skin_;
  double h_before = 0.0, elapsed = 0.0;
  for (std::int64_t k = 0; k < K_; ++k) {
    const double hk = k + 1 == K_ ? h_last_ : h_;
    const double half = 0.5 * hk;
    elapsed += hk;
    tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
      Result& r = parts[b];
      for (std::size_t u = b * kBlock; u < std::min(count, (b + 1) * kBlock); ++u)
        r.pairs += forces(span_members_[u], !all, r.max_ratio, r.violations);
    });
    tbb::parallel_for(std::size_t{0}, blocks, [&](std::size_t b) {
      Result& r = parts[b];
      for (std::size_t u = b * kBlock; u < std::min(count, (b + 1) * kBlock); ++u) {
        const std::uint32_t i = span_members_[u];
        double ex = 0.0, ey = 0.0, ez = 0.0;
        if constexpr (External)
          ex = ex_[i], ey = ey_[i], ez = ez_[i];
        const double im = p_.inv_mass[i];
        if (record && k == 0) {
          svx_[i] = p_.vx[i] + ((p_.fx[i] + ex) * im + m.gravity[0]) * hprev_[i];
          svy_[i] = p_.vy[i] + ((p_.fy[i] + ey) * im + m.gravity[1]) * hprev_[i];
          svz_[i] = p_.vz[i] + ((p_.fz[i] + ez) * im + m.gravity[2]) * hprev_[i];
        }
        const double s = k == 0 ? hprev_[i] + half : 0.5 * h_before + half;
        const double ims = im * s;
        kick_drift(p_.x[i], p_.vx[i], p_.fx[i] + ex, ims, m.gravity[0] * s, hk);
        kick_drift(p_.y[i], p_.vy[i], p_.fy[i] + ey, ims, m.gravity[1] * s, hk);
        kick_drift(p_.z[i], p_.vz[i], p_.fz[i] + ez, ims, m.gravity[2] * s, hk);
        hprev_[i] = half;
        if (all) {
          // Rows built at x_ref hold every pair within r_i + r_j + skin: a particle that moved
          // farther than skin/2 since may miss one; redo with a wider halo.
          const double dx = p_.x[i] - x_ref_[i], dy = p_.y[i] - y_ref_[i], dz = p_.z[i] - z_ref_[i];
          r.outran += dx * dx + dy * dy + dz * dz > half_skin2;
        } else {
          const double dx = p_.x[i] - x0_[i], dy = p_.y[i] - y0_[i], dz = p_.z[i] - z0_[i];
          const double reach = bound_[i] * elapsed + margin_;
          r.bound_violations += dx * dx + dy * dy + dz * dz > reach * reach;
        }
      }
    });
    if (k + 1 < K_)
      exchange_.forward(p_);
    h_before = hk;
  }
  span_result_ = Result{};
  for (const Result& r : parts) {
    span_result_.pairs += r.pairs, span_result_.violations += r.violations;
    span_result_.bound_violations += r.bound_violations, span_result_.outran += r.outran;
    span_result_.max_ratio = std::max(span_result_.max_ratio, r.max_ratio);
  }
}

void DistributedIslandsScheme::record_state() {
  const std::size_t n = owned_;
  sx_.resize(n), sy_.resize(n), sz_.resize(n), svx_.resize(n), svy_.resize(n), svz_.resize(n);
  sdt_.resize(n), sisland_.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    sx_[i] = geom_.wrap(p_.x[i], 0), sy_[i] = geom_.wrap(p_.y[i], 1),
    sz_[i] = geom_.wrap(p_.z[i], 2);
    const bool fine = global_ || island_of_[i] != kAlone;
    sisland_[i] = global_ ? 0 : fine ? static_cast<std::int64_t>(island_of_[i]) : -1;
    sdt_[i] = fine ? dt_sp_ / static_cast<double>(K_) : dt_sp_;
  }
  smass_.assign(p_.mass.begin(), p_.mass.begin() + static_cast<std::ptrdiff_t>(n));
  sradius_.assign(p_.radius.begin(), p_.radius.begin() + static_cast<std::ptrdiff_t>(n));
  sid_.assign(p_.id.begin(), p_.id.begin() + static_cast<std::ptrdiff_t>(n));
}

// A fresh build: migration to the owners (a new decomposition once dem.nsubit sub-iterations
// have passed since the last), ghosts and rows with a skin for several sub-iterations.
void DistributedIslandsScheme::rebuild() {
  p_.resize(owned_); // the ghosts go
  if (last_regrid_ < 0 || subits_ - last_regrid_ >= nsubit_) {
    regrid();
    last_regrid_ = subits_;
  }
  migrate();
  own_bounds();
  double b = 0.0;
  for (std::size_t i = 0; i < owned_; ++i)
    b = std::max(b, bound_[i]);
  const double speed = std::max(comm_.max(b), last_max_bound_);
  // IslandsScheme's islands skin (three times the explicit scheme's unless dem.neighbor_skin is
  // set), at least four sub-iterations of the largest bound, or what a failed build asked for.
  skin_ = std::max({base_skin_, 4.0 * speed * dt_sp_ + 2.0 * margin_, grown_skin_});
  build_ghosts_and_rows();
  need_rebuild_ = false;
}

void DistributedIslandsScheme::subiterate(bool record) {
  const FineSteps steps = fine_steps(dt_sp_, model_.dt);
  K_ = steps.K;
  h_ = steps.h;
  h_last_ = steps.h_last;
  // {owned, particle steps, pairs, overlaps beyond the bound, bound violations, faults, fine
  // members, spanning members, spanning island parts, outran, mass}
  std::array<double, 11> c{};
  std::uint32_t fault_index = 0;
  int fault = 0;
  double ratio = 0.0;
  for (;;) {
    {
      PhaseTimer::Scope t(timer_, Phase::neighbor);
      for (bool fresh = false;;) {
        if (need_rebuild_) {
          rebuild();
          fresh = true;
        } else {
          // The ghosts' positions, velocities and own bounds from their owners: one message round.
          own_bounds();
          const std::size_t n = p_.size();
          bound_.resize(n);
          std::vector<double>* cols[] = {&p_.x, &p_.y, &p_.z, &p_.vx, &p_.vy, &p_.vz, &bound_};
          exchange_.forward_columns(cols);
        }
        island_of_.assign(p_.size(), kAlone);
        busy_v_.clear();
        mark_.assign(p_.size(), 0);
        const double reach = link_rounds();
        if (2.0 * reach + margin_ < skin_)
          break;
        // Some pair could link that the rows (or the ghosts) miss: build again, wider when even
        // a fresh build was too short.
        if (fresh)
          grown_skin_ = std::max(2.0 * skin_, 2.2 * reach + 2.0 * margin_);
        need_rebuild_ = true;
        ++expired_builds_;
      }
    }
    x0_.assign(p_.x.begin(), p_.x.begin() + static_cast<std::ptrdiff_t>(owned_));
    y0_.assign(p_.y.begin(), p_.y.begin() + static_cast<std::ptrdiff_t>(owned_));
    z0_.assign(p_.z.begin(), p_.z.begin() + static_cast<std::ptrdiff_t>(owned_));
    vx0_.assign(p_.vx.begin(), p_.vx.begin() + static_cast<std::ptrdiff_t>(owned_));
    vy0_.assign(p_.vy.begin(), p_.vy.begin() + static_cast<std::ptrdiff_t>(owned_));
    vz0_.assign(p_.vz.begin(), p_.vz.begin() + static_cast<std::ptrdiff_t>(owned_));
    hp0_ = hprev_;
    PhaseTimer::Scope t(timer_, Phase::force);
    if (record)
      record_state();
    std::int64_t span_parts = 0, members = 0;
    span_members_.clear();
    results_.clear();
    span_result_ = Result{};
    if (global_) {
      ext_on_ ? fine_together<true>(record, true) : fine_together<false>(record, true);
      members = static_cast<std::int64_t>(owned_);
    } else {
      const std::uint32_t nc = islands_.count();
      members_.resize(busy_v_.size());
      for (std::size_t k = 0; k < busy_v_.size(); ++k)
        members_[k] = busy_v_[islands_.members[k]];
      for (std::uint32_t q = 0; q < nc; ++q)
        span_parts += spans_[q];
      for (const std::uint32_t i : busy_v_)
        if (i < owned_) {
          ++members;
          if (spans_[island_of_[i]])
            span_members_.push_back(i);
        }
      ext_on_ ? free_flight<true>(record) : free_flight<false>(record);
      results_.assign(nc, Result{});
      tbb::parallel_for(tbb::blocked_range<std::uint32_t>(0, nc, 1),
                        [&](const tbb::blocked_range<std::uint32_t>& r) {
                          for (std::uint32_t q = r.begin(); q != r.end(); ++q)
                            if (!spans_[q])
                              ext_on_ ? run_local_island<true>(q, record)
                                      : run_local_island<false>(q, record);
                        });
      if (spanning_global_ > 0) // some rank has a spanning island: every rank takes part
        ext_on_ ? fine_together<true>(record, false) : fine_together<false>(record, false);
    }
    c = {};
    c[0] = static_cast<double>(owned_);
    c[1] = static_cast<double>(static_cast<std::int64_t>(owned_) - members + members * K_);
    ratio = span_result_.max_ratio;
    for (const Result& r : results_) {
      c[2] += static_cast<double>(r.pairs), c[3] += static_cast<double>(r.violations);
      c[4] += static_cast<double>(r.bound_violations);
      ratio = std::max(ratio, r.max_ratio);
    }
    c[2] += static_cast<double>(span_result_.pairs);
    c[3] += static_cast<double>(span_result_.violations);
    c[4] += static_cast<double>(span_result_.bound_violations);
    c[9] = static_cast<double>(span_result_.outran);
    // Faults: NaN, or an owned particle outside a wall.
    fault = 0;
    for (std::uint32_t i = 0; i < owned_ && fault == 0; ++i) {
      const double q[3] = {p_.x[i], p_.y[i], p_.z[i]};
      const double v2 = p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i];
      if (!std::isfinite(v2 + q[0] + q[1] + q[2]))
        fault = 1, fault_index = i;
      for (int a = 0; a < 3 && fault == 0; ++a)
        if (!geom_.periodic[a] && !(q[a] >= geom_.lo[a] && q[a] <= geom_.hi[a]))
          fault = 2, fault_index = i;
    }
    c[5] = fault != 0;
    c[6] = static_cast<double>(members);
    c[7] = global_ ? 0.0 : static_cast<double>(span_members_.size()); // dense: not "spanning"
    c[8] = static_cast<double>(span_parts);
    for (std::size_t i = 0; i < owned_; ++i)
      c[10] += p_.mass[i];
    local_c_[0] = static_cast<std::int64_t>(c[1]), local_c_[1] = static_cast<std::int64_t>(c[2]);
    // One reduction closes the sub-iteration (the counts are exact in doubles below 2^53).
    comm_.sum(c);
    if (c[9] == 0 || c[5] > 0)
      break;
    // The dense mode outran its rows somewhere: every rank rolls back and widens the halo.
    std::copy(x0_.begin(), x0_.end(), p_.x.begin()),
        std::copy(y0_.begin(), y0_.end(), p_.y.begin());
    std::copy(z0_.begin(), z0_.end(), p_.z.begin());
    std::copy(vx0_.begin(), vx0_.end(), p_.vx.begin());
    std::copy(vy0_.begin(), vy0_.end(), p_.vy.begin());
    std::copy(vz0_.begin(), vz0_.end(), p_.vz.begin());
    hprev_ = hp0_;
    grown_skin_ = 2.0 * skin_;
    need_rebuild_ = true;
    ++retries_;
  }
  if (c[5] > 0) {
    std::string message;
    std::int64_t key = std::numeric_limits<std::int64_t>::max();
    if (fault != 0) {
      const std::uint32_t i = fault_index;
      key = p_.id[i];
      message = fmt::format(
          "t = {:.9g} s, sub-iteration {}: particle {} at ({:.6g}, {:.6g}, {:.6g}) m: {} (rank {})",
          time() + dt_sp_, subits_, p_.id[i], p_.x[i], p_.y[i], p_.z[i],
          fault == 1 ? "position or velocity is not finite (NaN/inf): the step is unstable"
                     : "left the domain through a wall",
          comm_.rank());
    }
    throw RunError(comm_.agree_on_error(key, message));
  }
  if (c[0] != static_cast<double>(n_global_) ||
      std::abs(c[10] - mass_global_) > 1e-9 * mass_global_)
    throw RunError(fmt::format("t = {:.9g} s: {} particles of total mass {:.17g} kg on the ranks "
                               "after migration, {} of {:.17g} kg expected",
                               time(), c[0], c[10], n_global_, mass_global_));
  if (global_)
    ++global_subits_;
  for (std::size_t i = 0; i < owned_; ++i)
    if (global_ || island_of_[i] != kAlone)
      fine_[i] += 1.0;
  auto count = [&](int q) { return static_cast<std::int64_t>(c[static_cast<std::size_t>(q)]); };
  particle_steps_ += count(1), pair_evaluations_ += count(2), overlap_violations_ += count(3);
  local_particle_steps_ += local_c_[0], local_pair_evaluations_ += local_c_[1];
  bound_violations_ += count(4);
  span_subits_ += count(7) > 0, span_particles_ += count(7), span_parts_ += count(8);
  const std::int64_t fine = count(6);
  last_fine_fraction_ =
      n_global_ > 0 ? static_cast<double>(fine) / static_cast<double>(n_global_) : 0.0;
  iv_fine_ += fine, iv_particles_ += n_global_, iv_steps_ += count(1);
  iv_min_ = std::min(iv_min_, fine < n_global_ ? std::int64_t{1} : K_);
  iv_max_ = std::max(iv_max_, fine > 0 ? K_ : std::int64_t{1});
  // The largest overlap is reduced only when the state is recorded (the orb scheme's budget).
  max_ratio_local_ = std::max(max_ratio_local_, ratio);
  if (record)
    max_overlap_ratio_ = std::max(max_overlap_ratio_, comm_.max(max_ratio_local_));
  ++subits_;
}

// What a restart cannot know is reset on both sides: the decomposition and ownership (the next
// build regrids and migrates), the skin grown by short builds, the last sub-iteration's largest
// bound, and each rank's own unrecorded overlap ratio (the largest over the ranks instead).
void DistributedIslandsScheme::canonicalize() {
  need_rebuild_ = true;
  last_regrid_ = -1;
  grown_skin_ = 0.0;
  last_max_bound_ = 0.0;
  max_ratio_local_ = comm_.max(max_ratio_local_);
}

IslandsScheme::State DistributedIslandsScheme::save_state() {
  canonicalize();
  IslandsScheme::State s;
  s.skin = skin_ > 0.0 ? skin_ : base_skin_;
  s.hprev.assign(hprev_.begin(), hprev_.begin() + static_cast<std::ptrdiff_t>(owned_));
  s.fine_subits.resize(owned_);
  for (std::size_t i = 0; i < owned_; ++i)
    s.fine_subits[i] = static_cast<std::int64_t>(fine_[i]);
  s.counters = {
      subits_,           particle_steps_, pair_evaluations_, builds_,       overlap_violations_,
      bound_violations_, global_subits_,  iv_fine_,          iv_particles_, iv_steps_,
      iv_min_,           iv_max_};
  s.max_overlap_ratio = max_overlap_ratio_;
  s.last_fine_fraction = last_fine_fraction_;
  s.rank_counters = {regrids_,     retries_,        expired_builds_,
                     span_subits_, span_particles_, span_parts_};
  s.rank_values = {max_ratio_local_};
  return s;
}

void DistributedIslandsScheme::restore_state(IslandsScheme::State s) {
  const bool fits = s.hprev.size() == owned_ && s.fine_subits.size() == owned_ &&
                    s.counters.size() == 12 &&
                    (s.rank_counters.empty() || s.rank_counters.size() == 6) &&
                    (s.rank_values.empty() || s.rank_values.size() == 1);
  if (comm_.max(fits ? 0.0 : 1.0) > 0.0)
    throw RunError("checkpoint: the islands scheme's state does not fit the particles");
  hprev_ = std::move(s.hprev);
  fine_.resize(owned_);
  for (std::size_t i = 0; i < owned_; ++i)
    fine_[i] = static_cast<double>(s.fine_subits[i]);
  const auto& k = s.counters;
  subits_ = k[0], particle_steps_ = k[1], pair_evaluations_ = k[2], builds_ = k[3];
  overlap_violations_ = k[4], bound_violations_ = k[5], global_subits_ = k[6];
  iv_fine_ = k[7], iv_particles_ = k[8], iv_steps_ = k[9], iv_min_ = k[10], iv_max_ = k[11];
  max_overlap_ratio_ = s.max_overlap_ratio;
  last_fine_fraction_ = s.last_fine_fraction;
  if (!s.rank_counters.empty()) {
    const auto& r = s.rank_counters;
    regrids_ = r[0], retries_ = r[1], expired_builds_ = r[2], span_subits_ = r[3];
    span_particles_ = r[4], span_parts_ = r[5];
  }
  max_ratio_local_ = s.rank_values.empty() ? max_overlap_ratio_ : s.rank_values[0];
  canonicalize();
}

LeafStepStats DistributedIslandsScheme::take_interval_stats() {
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

} // namespace cfddem::dem
