#include "dem/explicit_scheme.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/partitioner.h>

#include "core/error.hpp"
#include "dem/contact_damping.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/verlet_passes.hpp"

namespace cfddem::dem {

namespace {
constexpr std::uint32_t kNone = kNoParticle;
} // namespace

ParticleRange particle_range(const ParticleStore& p) {
  ParticleRange r;
  r.count = static_cast<std::int64_t>(p.size());
  r.m_min = r.r_min = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < p.size(); ++i) {
    r.m_min = std::min(r.m_min, p.mass[i]);
    r.m_max = std::max(r.m_max, p.mass[i]);
    r.r_min = std::min(r.r_min, p.radius[i]);
    r.r_max = std::max(r.r_max, p.radius[i]);
  }
  return r;
}

StepModel make_step_model(const Scene& s, const ParticleStore& p) {
  return make_step_model(s, particle_range(p));
}

StepModel make_step_model(const Scene& s, const ParticleRange& range) {
  StepModel m;
  const auto& d = s.dem;
  m.gravity = s.gravity;
  m.pair = {d.spring_constant, dashpot_coefficient(d.spring_constant, d.restitution)};
  m.wall = {d.wall_spring_constant, dashpot_coefficient(d.wall_spring_constant, d.wall_restitution)};
  m.friction = d.friction > 0.0 || d.wall_friction > 0.0;
  m.pair_t = {d.tangential_stiffness_ratio * d.spring_constant,
              d.tangential_damping_ratio * m.pair.eta_coef, d.friction};
  m.wall_t = {d.tangential_stiffness_ratio * d.wall_spring_constant,
              d.tangential_damping_ratio * m.wall.eta_coef, d.wall_friction};
  m.max_overlap = d.max_overlap;
  const bool empty = range.count == 0;
  const double m_min = empty ? 1.0 : range.m_min;
  const double r_min = empty ? 1.0 : range.r_min, r_max = empty ? 1.0 : range.r_max;
  m.r_min = r_min;
  m.uniform_mass = !empty && range.m_min == range.m_max;
  if (m.uniform_mass) {
    m.uniform_meff = 0.5 * range.m_min;
    m.uniform_eta = m.pair.eta_coef * std::sqrt(m.uniform_meff); // docs/theory.md §2: eta_n
  }
  const double k_max = std::max(d.spring_constant, d.wall_spring_constant);
  const double tau_p = std::sqrt(m_min / k_max);
  m.dt = d.dt > 0.0 ? d.dt : tau_p * d.dt_factor;
  // Stiffest oscillator: two of the lightest particles (m_eff = m/2) or one against a wall.
  const double omega = std::max(std::sqrt(2.0 * d.spring_constant / m_min),
                                std::sqrt(d.wall_spring_constant / m_min));
  // Known before any step: a configuration error (exit 2), named by its keys.
  if (omega * m.dt >= 2.0)
    throw ConfigError(
        d.dt > 0.0 ? "scene key 'dem.dt'" : "scene key 'dem.dt_factor'",
        fmt::format(
            "unstable time step: omega dt = {:.4g} >= 2 for the stiffest contact (dt = {:.4g} s, "
            "dem.dt_factor = {}, dem.dt = {}); velocity Verlet on a spring needs omega dt < 2, and "
            "accuracy needs far less (dem.dt_factor = 0.02 gives 0.028)",
            omega * m.dt, m.dt, d.dt_factor, d.dt));
  m.skin = d.neighbor_skin > 0 ? d.neighbor_skin : 0.5 * r_max; // 0.25 d_max (the peers' skin)
  return m;
}

ExplicitScheme::ExplicitScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain),
      model_(make_step_model(scene, particles)) {
  if (model_.friction) p_.enable_rotation();
}

void ExplicitScheme::rebuild() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  if (!model_.friction) {
    list_.build(p_, geom_, model_.skin);
  } else {
    // Carry the tangential history of each pair across the rebuild, keyed by particle ids.
    std::unordered_map<std::int64_t, std::uint32_t> old_index;
    old_index.reserve(p_.size());
    for (std::size_t i = 0; i < p_.size(); ++i) old_index[p_.id[i]] = static_cast<std::uint32_t>(i);
    const std::vector<std::uint32_t> old_off(list_.offsets().begin(), list_.offsets().end());
    const std::vector<std::uint32_t> old_nb(list_.neighbors().begin(), list_.neighbors().end());
    std::vector<std::int64_t> old_ids(p_.id);
    std::vector<double> ohx(std::move(hx_)), ohy(std::move(hy_)), ohz(std::move(hz_));
    list_.build(p_, geom_, model_.skin);
    const auto off = list_.offsets();
    const auto nb = list_.neighbors();
    hx_.assign(nb.size(), 0.0), hy_.assign(nb.size(), 0.0), hz_.assign(nb.size(), 0.0);
    if (!old_off.empty()) {
      for (std::size_t i = 0; i + 1 < off.size(); ++i) {
        const std::uint32_t oi = old_index[p_.id[i]];
        for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
          const std::int64_t jid = p_.id[nb[k]];
          for (std::uint32_t q = old_off[oi]; q < old_off[oi + 1]; ++q)
            if (old_ids[old_nb[q]] == jid) {
              hx_[k] = ohx[q], hy_[k] = ohy[q], hz_[k] = ohz[q];
              break;
            }
        }
      }
    }
  }
  ext_.permute(list_.order()); // the build permuted the store: external forces follow
  // Only particles with a row get their contact force rewritten each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (p_.rotation) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
  }
  ++builds_;
  need_rebuild_ = false;
}

template <bool Friction> void ExplicitScheme::contact_pass(double dt, Report& out) {
  dem::contact_pass<Friction>(p_, list_, geom_, model_, hx_.data(), hy_.data(), hz_.data(), dt,
                              list_.active(), out);
}


template <bool Walls, bool Friction, bool External>
void ExplicitScheme::update_pass(double dt, Report& out) {
  dem::update_pass<Walls, Friction, External>(p_, p_.size(), list_, ext_, geom_, model_, dt, out);
}

template <bool Walls> void ExplicitScheme::update(double dt, Report& rep) {
  if (model_.friction) {
    ext_.active() ? update_pass<Walls, true, true>(dt, rep) : update_pass<Walls, true, false>(dt, rep);
  } else {
    ext_.active() ? update_pass<Walls, false, true>(dt, rep)
              : update_pass<Walls, false, false>(dt, rep);
  }
}

void ExplicitScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                        std::span<const double> fz) {
  ext_.set(fx, fy, fz, p_.size());
}

void ExplicitScheme::evaluate_and_update(double dt, Report& rep) {
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  {
    PhaseTimer::Scope t(timer_, Phase::force);
    model_.friction ? contact_pass<true>(dt, rep) : contact_pass<false>(dt, rep);
  }
  // Wall forces are evaluated inside the update pass and timed with it.
  PhaseTimer::Scope t(timer_, Phase::integrate);
  walls ? update<true>(dt, rep) : update<false>(dt, rep);
}

std::string describe_fault(const ParticleStore& p, const StepReport& r, const StepModel& m) {
  const std::uint32_t i = r.bad;
  const std::string who = fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) m", p.id[i],
                                      p.x[i], p.y[i], p.z[i]);
  std::string why;
  switch (r.fault) {
  case StepFault::nan:
    why = "position or velocity is not finite (NaN/inf): the step is unstable";
    break;
  case StepFault::overlap:
    why = r.partner == kNone
              ? fmt::format("overlap with a wall is {:.3g} of its radius (dem.max_overlap = {}): "
                            "the impact is too fast for the spring (raise k or lower dt)",
                            r.value, m.max_overlap)
              : fmt::format("overlap with particle {} is {:.3g} of the smaller radius "
                            "(dem.max_overlap = {}): the impact is too fast for the spring "
                            "(raise k or lower dt)",
                            p.id[r.partner], r.value, m.max_overlap);
    break;
  case StepFault::speed:
    why = fmt::format("speed {:.4g} m/s moves it more than the smallest radius in one step "
                      "(dt = {:.4g} s): contacts could be missed (tunnelling)",
                      r.value, m.dt);
    break;
  case StepFault::left_domain:
    why = fmt::format("left the domain through a wall (coordinate {:.6g} m)", r.value);
    break;
  case StepFault::none:
    break;
  }
  return who + ": " + why;
}

void ExplicitScheme::raise(const Report& r, double t) const {
  throw RunError(fmt::format("t = {:.9g} s, step {}: {}", t, steps_, describe_fault(p_, r, model_)));
}

void ExplicitScheme::start() {
  rebuild();
  // Forces at t = 0 with v(0) (dt = 0 leaves x and v unchanged), then v(-dt/2) = v(0) - a(0) dt/2.
  Report rep;
  evaluate_and_update(0.0, rep);
  if (rep.bad != kNone && rep.fault == StepFault::overlap) raise(rep, 0.0);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < p_.size(); ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    p_.vx[i] -= ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    p_.vy[i] -= ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    p_.vz[i] -= ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
    if (model_.friction) {
      p_.wx[i] -= p_.tx[i] * p_.inv_inertia[i] * h;
      p_.wy[i] -= p_.ty[i] * p_.inv_inertia[i] * h;
      p_.wz[i] -= p_.tz[i] * p_.inv_inertia[i] * h;
    }
  }
}

void ExplicitScheme::record_synchronised() {
  // x(n) and v(n) = v(n-1/2) + a(n) dt/2, with a(n) from the forces just evaluated.
  const std::size_t n = p_.size();
  sx_ = p_.x, sy_ = p_.y, sz_ = p_.z;
  svx_.resize(n), svy_.resize(n), svz_.resize(n);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < n; ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    svx_[i] = p_.vx[i] + ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    svy_[i] = p_.vy[i] + ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    svz_[i] = p_.vz[i] + ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
  }
}

void ExplicitScheme::step(bool record) {
  if (need_rebuild_) rebuild();
  Report rep;
  if (!record) {
    evaluate_and_update(model_.dt, rep);
  } else {
    // Split so the state at time n can be recorded between the force and the update.
    const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
    const bool fr = model_.friction;
    {
      PhaseTimer::Scope t(timer_, Phase::force);
      fr ? contact_pass<true>(model_.dt, rep) : contact_pass<false>(model_.dt, rep);
    }
    PhaseTimer::Scope t(timer_, Phase::integrate);
    if (walls) {
      // Wall forces are added inside the update pass; record after a force-only wall pass would
      // double count, so record with the wall forces applied by a dt = 0 update.
      fr ? update_pass<true, true, false>(0.0, rep) : update_pass<true, false, false>(0.0, rep);
      record_synchronised();
      // The dt = 0 pass left x, v unchanged and F including walls; finish with a pure update.
      update<false>(model_.dt, rep);
    } else {
      record_synchronised();
      update<false>(model_.dt, rep);
    }
  }
  if (rep.bad != kNone) raise(rep, time());
  ++steps_;
  particle_steps_ += static_cast<std::int64_t>(p_.size());
  pair_evaluations_ += static_cast<std::int64_t>(list_.pair_count());
  if (rep.moved > 0) need_rebuild_ = true;
}

ExplicitScheme::State ExplicitScheme::save_state() const {
  State s;
  s.offsets.assign(list_.offsets().begin(), list_.offsets().end());
  s.neighbors.assign(list_.neighbors().begin(), list_.neighbors().end());
  s.x_ref.assign(list_.x_ref().begin(), list_.x_ref().end());
  s.y_ref.assign(list_.y_ref().begin(), list_.y_ref().end());
  s.z_ref.assign(list_.z_ref().begin(), list_.z_ref().end());
  s.hx = hx_, s.hy = hy_, s.hz = hz_;
  s.skin = list_.skin();
  s.need_rebuild = need_rebuild_;
  s.steps = steps_, s.particle_steps = particle_steps_;
  s.pair_evaluations = pair_evaluations_, s.builds = builds_;
  return s;
}

void ExplicitScheme::restore_state(State s) {
  const std::size_t n = p_.size();
  const bool listed = !s.offsets.empty();
  check_saved_list(n, s.offsets, s.neighbors, s.x_ref, s.y_ref, s.z_ref);
  if (model_.friction && (s.hx.size() != s.neighbors.size() || s.hy.size() != s.neighbors.size() ||
                          s.hz.size() != s.neighbors.size()))
    throw RunError("checkpoint: the tangential history does not fit the neighbor list");
  list_.restore(std::move(s.offsets), std::move(s.neighbors), std::move(s.x_ref),
                std::move(s.y_ref), std::move(s.z_ref), s.skin, geom_);
  hx_ = std::move(s.hx), hy_ = std::move(s.hy), hz_ = std::move(s.hz);
  need_rebuild_ = s.need_rebuild || !listed;
  steps_ = s.steps, particle_steps_ = s.particle_steps;
  pair_evaluations_ = s.pair_evaluations, builds_ = s.builds;
}

} // namespace cfddem::dem
