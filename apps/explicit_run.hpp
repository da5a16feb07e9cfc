// The explicit scheme's adapter for the time loop (apps/scheme_runs.hpp): one step of dt per
// particle step, velocities staggered by half a step.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/gas_side.hpp"
#include "apps/rank_checkpoint.hpp"
#include "apps/rank_parts.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/state_edit.hpp"

namespace cfddem::apps {

template <class S> class ExplicitRun {
public:
  static constexpr bool kSub = false;
  static constexpr const char* kName = "explicit";
  using Restart = RestartShare<int>;

  static ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                                 const Communicator& comm, const std::string&, Restart& r) {
    // The history rows of a checkpoint with friction become records by id before the
    // particles are handed out (restore() gives each to the particle's owner).
    const RankParts parts(comm);
    if (parts.ranks && ck)
      r.history = saved_contact_history(*ck);
    return parts.particles(scene, ck, comm, r.taken);
  }

  ExplicitRun(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
              const Communicator& comm, PhaseTimer& timer, const dem::StepClock& step_clock)
      : scheme(RankParts(comm).make<S>(scene, p, range, comm, timer, step_clock)), parts_(comm),
        p_(p) {}

  S scheme;
  double dt() const { return scheme.dt(); }
  double fine_dt() const { return scheme.dt(); }
  long long steps() const { return scheme.steps_taken(); }
  std::size_t owned() const { return parts_.owned(scheme, p_); }
  long long checkpoint_every(long long every) const { return every; }
  bool auto_length() const { return false; }
  long long begin_interval() { return 1; }
  void begin_completion() {}
  void start() { scheme.start(); }
  // In place of start(). held: the gas force held at the checkpoint (null without a gas).
  void restore(Checkpoint& ck, Restart& r, const std::array<std::vector<double>, 3>* held) {
    if (parts_.ranks) {
      // The force travels with its particle to the owner restore() sends it to.
      if (held)
        scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
      const auto& st = std::get<dem::ExplicitScheme::State>(ck.scheme_state);
      scheme.restore({held ? st.steps : ck.step, st.particle_steps, st.pair_evaluations, st.builds},
                     r.history);
    } else {
      auto& st = std::get<dem::ExplicitScheme::State>(ck.scheme_state);
      if (st.x_ref.empty() && !st.offsets.empty()) {
        // An R-rank checkpoint with friction: its rows hold only the contact history, over the
        // saved particles (the store's order here). Reinstated as a list due for a rebuild, they
        // are carried over by ids as any rebuild carries the history.
        st.x_ref = p_.x, st.y_ref = p_.y, st.z_ref = p_.z;
        st.need_rebuild = true;
      }
      scheme.restore_state(std::move(st));
      if (held)
        scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
    }
  }
  // Particles leaving or entering (apps/particle_flux.hpp): the state restore() takes, as a
  // restart's `ck` and `r`. R ranks: the canonical state (canonicalize() reorders the store), the
  // counters and this rank's contact history by id; `owners` keeps the decomposition (the gas
  // boxes) for the scheme rebuilt on the particles that stay.
  void save_for_change(Checkpoint& c, Restart& r,
                       std::optional<partition::RankDecomposition>& owners) {
    if (parts_.ranks) {
      scheme.canonicalize();
      r.history = scheme.contact_history();
      const auto k = scheme.counters();
      auto& st = dem::state_of<dem::ExplicitScheme::State>(c.scheme_state);
      st.steps = k.steps, st.particle_steps = k.particle_steps;
      st.pair_evaluations = k.pair_evaluations, st.builds = k.builds;
      owners = scheme.decomposition();
    } else {
      c.scheme_state = scheme.save_state();
    }
  }
  // That state without the particles `k` removes (`ids`: this rank's owned ids before).
  static void erase_removed(Checkpoint& c, Restart& r, const dem::Compaction& k,
                            std::span<const std::int64_t> ids) {
    dem::erase_removed(std::get<dem::ExplicitScheme::State>(c.scheme_state), k);
    k.apply_history(r.history, ids);
  }
  // And with the particles (x, y, z) appended to the store after those.
  static void admit(Checkpoint& c, Restart&, std::span<const std::int64_t> ids,
                    std::span<const double> x, std::span<const double> y,
                    std::span<const double> z) {
    dem::admit(std::get<dem::ExplicitScheme::State>(c.scheme_state), ids, x, y, z);
  }
  // One step; `k`: its index; the row's step statistics (every step a full one).
  dem::LeafStepStats advance(bool /*record*/, bool sync, long long k_last_row, long long& k) {
    scheme.step(sync);
    k = scheme.steps_taken() - 1;
    const auto steps = static_cast<double>(k - k_last_row);
    return {steps, steps, steps, 1.0};
  }
  void hold_gas_force(const GasSide::Force& f) { scheme.set_external_force(f[0], f[1], f[2]); }
  // R ranks with a gas: the particles owned by the gas boxes (`now`: moved at once, else at
  // start()).
  void own_by(partition::RankDecomposition d, bool now) {
    if (parts_.ranks) {
      scheme.set_decomposition(std::move(d));
      if (now)
        scheme.redistribute_now();
    }
  }
  // The velocities at t = 0 from the half-step ones start() left (v(-dt/2) + a dt/2).
  bool initial_velocities(std::vector<double> (&v)[3]) const {
    const std::size_t n = owned();
    const double h = 0.5 * scheme.dt();
    const auto& g = scheme.model().gravity;
    const std::vector<double>* f[3] = {&p_.fx, &p_.fy, &p_.fz};
    const std::vector<double>* u[3] = {&p_.vx, &p_.vy, &p_.vz};
    for (int a = 0; a < 3; ++a) {
      v[a].resize(n);
      for (std::size_t i = 0; i < n; ++i)
        v[a][i] = (*u[a])[i] + ((*f[a])[i] * p_.inv_mass[i] + g[static_cast<std::size_t>(a)]) * h;
    }
    return true;
  }
  SyncedParticles synced() const {
    const auto s = scheme.synchronised_previous();
    const std::size_t n = s.x.size();
    return {s.x,
            s.y,
            s.z,
            s.vx,
            s.vy,
            s.vz,
            {p_.mass.data(), n},
            {p_.radius.data(), n},
            {p_.id.data(), n},
            {},
            {}};
  }
  // The ORB box of each (wrapped) position: the decomposition in a snapshot (R ranks).
  std::vector<std::int64_t> boxes(std::span<const double> x, std::span<const double> y,
                                  std::span<const double> z) const {
    std::vector<std::int64_t> box;
    if (parts_.ranks)
      for (std::size_t i = 0; i < x.size(); ++i)
        box.push_back(scheme.decomposition().tree.locate(x[i], y[i], z[i]));
    return box;
  }
  // The particles and the scheme state into rank 0's checkpoint. Collective.
  void save(Checkpoint& c, const Communicator& comm) {
    if (parts_.ranks) {
      scheme.canonicalize();
      gather_rank_particles(scheme, p_, comm, c);
    } else {
      c.particles = p_;
      c.scheme_state = scheme.save_state();
    }
  }

  std::string banner(long long n_end) const {
    return fmt::format("dt = {:.4e} s, {} steps", scheme.dt(), n_end);
  }
  std::string banner_tail() const {
    if (parts_.ranks)
      return fmt::format(", {} boxes", 1 << scheme.levels());
    else
      return {};
  }
  static constexpr const char* kStepWord = "step";
  static constexpr const char* kStepsWord = "steps";
  std::string progress(long long k, double frac, double wall, const std::string& eta) const {
    return fmt::format("step {:>10} t = {:.6e} s ({:5.1f}%)  {:.3e} particle-steps/s  ETA {}", k,
                       scheme.time(), 100 * frac,
                       static_cast<double>(scheme.particle_steps()) / wall, eta);
  }
  void describe(nlohmann::ordered_json& j, const std::vector<std::vector<double>>&) const {
    j["dt"] = scheme.dt();
    j["steps"] = scheme.steps_taken();
  }
  const char* phase_note() const {
    return parts_.ranks
               ? "rank 0's phases; regrid: the parallel ORB; neighbor: migration, ghost exchange "
                 "and the local list; force: includes waiting for the ghost forward (after the "
                 "interior "
                 "rows); other: mostly posting the forward and the per-step flag reduction"
               : nullptr;
  }
  const char* force_definition() const {
    return parts_.ranks ? "neighbor-list pairs evaluated (each pair once per step), over all ranks"
                        : "neighbor-list pairs evaluated (each pair once per step)";
  }
  void describe_balance(nlohmann::ordered_json& j) const {
    if (parts_.ranks) {
      j["boxes"] = 1 << scheme.levels();
      j["regrid_policy"] = "ORB + Hilbert knapsack at the first neighbor rebuild after "
                           "dem.regrid_interval; migration and ghosts at every rebuild";
      nlohmann::ordered_json regrids = nlohmann::ordered_json::array();
      double worst = 1.0;
      for (const auto& r : scheme.regrids()) {
        regrids.push_back({{"step", r.step}, {"imbalance", r.imbalance}});
        worst = std::max(worst, r.imbalance);
      }
      j["load_imbalance"] = regrids;
      j["load_imbalance_definition"] = "per regrid: max over ranks / mean of particles owned";
      j["load_imbalance_max"] = worst;
    }
  }
  std::string performance(const PhaseTimer& t, double pss, double wait_max) const {
    if (parts_.ranks)
      return fmt::format("Performance: {:.4g} particle-steps/s; rank 0: neighbor+exchange {:.3g} "
                         "s ({} builds, {} regrids), force {:.3g} s, integrate {:.3g} s; MPI "
                         "wait max {:.3g} s",
                         pss, t.rebuild_seconds(), scheme.neighbor_builds(),
                         scheme.regrids().size(), t.seconds(Phase::force),
                         t.seconds(Phase::integrate), wait_max);
    else
      return fmt::format("Performance: {:.4g} particle-steps/s; neighbor {:.3g} s ({} builds), "
                         "force {:.3g} s, integrate {:.3g} s, io {:.3g} s",
                         pss, t.rebuild_seconds(), scheme.neighbor_builds(),
                         t.seconds(Phase::force), t.seconds(Phase::integrate),
                         t.seconds(Phase::io));
  }

private:
  RankParts parts_;
  ParticleStore& p_;
};

} // namespace cfddem::apps
