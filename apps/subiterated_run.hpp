// What the two sub-iterated schemes' adapters for the time loop share (apps/scheme_runs.hpp):
// one sub-iteration of dt_sp per particle step, the state saved and restored whole, and the
// run's lines and run.json entries that read alike for both. OrbRun (apps/orb_run.hpp) and
// IslandsRun (apps/islands_run.hpp) add what their scheme differs in.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <utility>
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
#include "dem/state_edit.hpp"

namespace cfddem::apps {

// S: the scheme, whose state a one-rank checkpoint holds whole (Checkpoint::scheme_state).
template <class S> class SubiteratedRunBase {
public:
  static constexpr bool kSub = true;
  using State = typename S::State;
  using Restart = RestartShare<State>;

  static ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                                 const Communicator& comm, const std::string& path, Restart& r) {
    const std::size_t n_saved = ck ? ck->particles.size() : 0;
    const RankParts parts(comm);
    ParticleStore p = parts.particles(scene, ck, comm, r.taken);
    if (parts.ranks && ck)
      r.state = subiterated_share<S>(*ck, r.taken, n_saved, path);
    return p;
  }

  SubiteratedRunBase(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
                     const Communicator& comm, PhaseTimer& timer, const dem::StepClock& step_clock)
      : scheme(RankParts(comm).make<S>(scene, p, range, comm, timer, step_clock)), parts_(comm),
        p_(p) {}

  S scheme;
  double fine_dt() const { return scheme.dt_fine(); }
  long long steps() const { return scheme.subiterations(); }
  std::size_t owned() const { return parts_.owned(scheme, p_); }
  void start() { scheme.start(); }
  void restore(Checkpoint& ck, Restart& r, const std::array<std::vector<double>, 3>* held) {
    if (parts_.ranks)
      scheme.restore_state(std::move(*r.state));
    else
      scheme.restore_state(std::move(std::get<State>(ck.scheme_state)));
    if (held)
      scheme.set_external_force((*held)[0], (*held)[1], (*held)[2]);
  }
  // Particles leaving or entering (apps/particle_flux.hpp): the state restore() takes, as a
  // restart's `ck` and `r` (R ranks: the canonical state, in the store's order after it).
  void save_for_change(Checkpoint& c, Restart& r, std::optional<partition::RankDecomposition>&) {
    if (parts_.ranks)
      r.state = scheme.save_state();
    else
      c.scheme_state = scheme.save_state();
  }
  // That state without the particles `k` removes (`ids`: this rank's owned ids before).
  static void erase_removed(Checkpoint& c, Restart& r, const dem::Compaction& k,
                            std::span<const std::int64_t> ids) {
    dem::erase_removed(r.state ? *r.state : std::get<State>(c.scheme_state), k, ids);
  }
  // And with the particles (x, y, z) appended to the store after those (`ids`: the store's ids
  // before them).
  static void admit(Checkpoint& c, Restart& r, std::span<const std::int64_t> ids,
                    std::span<const double> x, std::span<const double> y,
                    std::span<const double> z) {
    dem::admit(r.state ? *r.state : std::get<State>(c.scheme_state), ids, x, y, z);
  }
  // One sub-iteration; `k`: its index; the row's statistics of the interval it closes.
  dem::LeafStepStats advance(bool record, bool sync, long long /*k_last_row*/, long long& k) {
    const dem::LeafStepStats ls = record ? scheme.take_interval_stats() : dem::LeafStepStats{};
    scheme.subiterate(sync);
    k = scheme.subiterations() - 1;
    return ls;
  }
  // An adaptive fluid.dt: the next fluid step's length, divided into the sub-iterations.
  void set_interval(double interval) { scheme.set_interval(interval); }
  // The owed half kick is settled with the old force (replace_external_force).
  void hold_gas_force(const GasSide::Force& f) { scheme.replace_external_force(f[0], f[1], f[2]); }
  void own_by(const partition::RankDecomposition&, bool) {} // by the leaves, routed to the gas
  bool initial_velocities(std::vector<double> (&)[3]) const { return false; }
  SyncedParticles synced() const {
    const auto s = scheme.synchronised_previous();
    return {s.x, s.y, s.z, s.vx, s.vy, s.vz, s.mass, s.radius, s.id, s.leaf, s.local_dt};
  }
  std::vector<std::int64_t> boxes(std::span<const double>, std::span<const double>,
                                  std::span<const double>) const {
    return {};
  }
  void save(Checkpoint& c, const Communicator& comm) {
    if (parts_.ranks) {
      gather_subiterated(scheme, p_, comm, c);
    } else {
      c.particles = p_;
      c.scheme_state = scheme.save_state();
    }
  }

  std::string banner_tail() const { return {}; }
  static constexpr const char* kStepWord = "sub-iteration";
  static constexpr const char* kStepsWord = "sub-iterations";

protected:
  // The banner with a fixed dt_sp; `detail`: what follows the scheme's name (orb: its leaves).
  std::string fixed_banner(const char* name, const std::string& detail, long long n_end) const {
    return fmt::format("{} scheme{}, dt_sp = {:.4e} s (fine dt = {:.4e} s), {} sub-iterations",
                       name, detail, scheme.dt_sub(), scheme.dt_fine(), n_end);
  }
  // `at`: the step's place; `fine`: what the fine fraction counts (leaves or particles).
  std::string progress_line(const std::string& at, double frac, const char* fine,
                            const std::string& eta) const {
    return fmt::format("{} t = {:.6e} s ({:5.1f}%)  fine {} {:.2f}  ETA {}", at, scheme.time(),
                       100 * frac, fine, scheme.last_fine_fraction(), eta);
  }
  // run.json's entries after dt, dt_sp (and orb's leaves); `regrids`: whether the scheme
  // regrids (orb always, islands on R ranks only).
  void describe_steps(nlohmann::ordered_json& j, bool regrids) const {
    j["steps"] = scheme.subiterations();
    j["steps_definition"] = "sub-iterations of dt_sp (one past the end, as the explicit loop)";
    if (regrids) {
      j["regrids"] = scheme.regrids();
      j["subiteration_retries"] = scheme.retries();
    }
    j["final_skin"] = scheme.skin();
    j["max_overlap_ratio"] = scheme.max_overlap_ratio();
    j["overlap_violations"] = scheme.overlap_violations();
  }
  // R ranks: the regrids' imbalance; `policy`: when the scheme regrids and migrates.
  void describe_regrids(nlohmann::ordered_json& j, const char* policy) const {
    if (parts_.ranks) {
      j["regrid_policy"] = policy;
      double worst = 1.0;
      for (const double q : scheme.imbalances())
        worst = std::max(worst, q);
      j["load_imbalance"] = scheme.imbalances();
      j["load_imbalance_definition"] = "per regrid in this run: max over ranks / mean of the "
                                       "knapsack weight (orb: particles, or particles x local "
                                       "steps; islands: particles)";
      j["load_imbalance_max"] = worst;
    }
  }
  // The closing performance line. One rank: `neighbor` and `force` name the two phases' work;
  // R ranks: `tail` follows the overlaps.
  std::string performance_line(const PhaseTimer& t, double pss, double wait_max,
                               const char* neighbor, const char* force,
                               const std::string& tail) const {
    if (parts_.ranks)
      return fmt::format("Performance: {:.4g} particle-steps/s; {} force evaluations; rank 0: "
                         "neighbor+exchange {:.3g} s, stepping {:.3g} s; MPI wait max {:.3g} s; "
                         "max overlap {:.3g} r ({} beyond dem.max_overlap){}",
                         pss, scheme.pair_evaluations(), t.rebuild_seconds(),
                         t.seconds(Phase::force), wait_max, scheme.max_overlap_ratio(),
                         scheme.overlap_violations(), tail);
    return fmt::format("Performance: {:.4g} particle-steps/s; {} force evaluations; {} {:.3g} "
                       "s, {} {:.3g} s, io {:.3g} s; max overlap {:.3g} r ({} beyond "
                       "dem.max_overlap)",
                       pss, scheme.pair_evaluations(), neighbor, t.rebuild_seconds(), force,
                       t.seconds(Phase::force), t.seconds(Phase::io), scheme.max_overlap_ratio(),
                       scheme.overlap_violations());
  }

  RankParts parts_;
  ParticleStore& p_;
};

} // namespace cfddem::apps
