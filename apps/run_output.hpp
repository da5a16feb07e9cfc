// What every run loop writes: the diagnostics columns and rows (with the particles' mean
// velocity and acceleration, and the gas's diagnostics), run.json's common parts, and the
// progress line's ETA, for the one time loop (apps/run_loop.hpp).
#pragma once

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/census_columns.hpp"
#include "apps/coupled_step.hpp"
#include "apps/derived_numbers.hpp"
#include "core/communicator.hpp"
#include "core/message_counts.hpp"
#include "core/parallel_env.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "core/simd_level.hpp"
#include "dem/granular_diagnostics.hpp"

namespace cfddem::apps {

using clock = std::chrono::steady_clock;

inline double seconds_since(clock::time_point t0) {
  return std::chrono::duration<double>(clock::now() - t0).count();
}

// The columns of diagnostics.csv. With output.contact_census on, the census's columns
// (apps/census_columns.hpp) follow these; off, they are not written at all.
inline const std::vector<std::string> kBaseColumns = {
    "time",       "step",       "granular_temperature", "kinetic_energy", "mean_speed",
    "mean_x",     "mean_y",     "mean_z",               "momentum_x",     "momentum_y",
    "momentum_z", "particles",  "particle_steps",       "force_evaluations", "neighbor_builds",
    "wall_seconds", "leaf_steps_min", "leaf_steps_mean", "leaf_steps_max", "fine_leaf_fraction",
    "pressure_drop", "gas_momentum_x", "gas_momentum_y", "gas_momentum_z", "mean_vx", "mean_vy",
    "mean_vz", "mean_ax", "mean_ay", "mean_az", "gas_mass_residual", "particle_mass", "mass_in",
    "mass_out"};
// The columns before particle_mass, mass_in and mass_out were added: a checkpoint that holds them
// is read with those three appended (apps/checkpoint.cpp, upgrade_columns).
inline const std::size_t kColumnsBeforeMassBalance = static_cast<std::size_t>(
    std::find(kBaseColumns.begin(), kBaseColumns.end(), "particle_mass") - kBaseColumns.begin());

inline std::vector<std::string> diagnostics_columns(bool census) {
  std::vector<std::string> c = kBaseColumns;
  if (census)
    c.insert(c.end(), census_columns().begin(), census_columns().end());
  return c;
}

// Columns added by the gas issue: fluid diagnostics (0 without a fluid) and particle means.
// mean_a is the change of the mean velocity over the output interval divided by its length (0
// in the first row): the interval-averaged mean acceleration, free of contact noise.
struct RowExtra {
  FluidDiagnostics fluid;
  std::array<double, 3> mean_v{}, mean_a{};
};

// The particles' mass balance of a row [kg]: held now, and in and out through the faces since the
// start of the run: held(t) = held(0) + in - out.
struct ParticleMass {
  double held = 0.0, in = 0.0, out = 0.0;
};

class MeanTracker {
public:
  RowExtra next(double t, std::span<const double> vx, std::span<const double> vy,
                std::span<const double> vz, const FluidDiagnostics& fd = {}) {
    const std::span<const double> v[3] = {vx, vy, vz};
    std::array<double, 3> mean{};
    for (int a = 0; a < 3; ++a) {
      double sum = 0.0;
      for (double q : v[a]) sum += q;
      mean[a] = v[a].empty() ? 0.0 : sum / static_cast<double>(v[a].size());
    }
    return next(t, mean, fd);
  }
  // The mean velocity already known (over all ranks).
  RowExtra next(double t, const std::array<double, 3>& mean_v, const FluidDiagnostics& fd = {}) {
    RowExtra e;
    e.fluid = fd;
    e.mean_v = mean_v;
    for (int a = 0; a < 3; ++a)
      e.mean_a[a] = has_ && t > t_ ? (e.mean_v[a] - v_[a]) / (t - t_) : 0.0;
    has_ = true, t_ = t, v_ = e.mean_v;
    return e;
  }
  // Continue after a restart from the last row written before the checkpoint.
  void resume(const std::vector<double>& last_row) {
    const auto col = [](const char* name) {
      return static_cast<std::size_t>(
          std::find(kBaseColumns.begin(), kBaseColumns.end(), name) - kBaseColumns.begin());
    };
    has_ = true;
    t_ = last_row[col("time")];
    v_ = {last_row[col("mean_vx")], last_row[col("mean_vy")], last_row[col("mean_vz")]};
  }

private:
  bool has_ = false;
  double t_ = 0.0;
  std::array<double, 3> v_{};
};

template <class Scheme>
inline std::vector<double> row(double t, long long step, const dem::GranularState& s, std::size_t n,
                        const Scheme& scheme, double wall, const dem::LeafStepStats& ls,
                        const RowExtra& x, const ParticleMass& m,
                        const std::vector<double>& census) {
  std::vector<double> r = {t,
          static_cast<double>(step),
          s.granular_temperature,
          s.kinetic_energy,
          s.mean_speed,
          s.mean_position[0],
          s.mean_position[1],
          s.mean_position[2],
          s.momentum[0],
          s.momentum[1],
          s.momentum[2],
          static_cast<double>(n),
          static_cast<double>(scheme.particle_steps()),
          static_cast<double>(scheme.pair_evaluations()),
          static_cast<double>(scheme.neighbor_builds()),
          wall,
          ls.steps_min,
          ls.steps_mean,
          ls.steps_max,
          ls.fine_fraction,
          x.fluid.pressure_drop,
          x.fluid.gas_momentum[0],
          x.fluid.gas_momentum[1],
          x.fluid.gas_momentum[2],
          x.mean_v[0],
          x.mean_v[1],
          x.mean_v[2],
          x.mean_a[0],
          x.mean_a[1],
          x.mean_a[2],
          x.fluid.mass_residual,
          m.held,
          m.in,
          m.out};
  r.insert(r.end(), census.begin(), census.end());
  return r;
}


inline std::string format_eta(double s) {
  if (!std::isfinite(s)) return "?";
  if (s < 120) return fmt::format("{:.0f}s", s);
  if (s < 7200) return fmt::format("{:.1f}min", s / 60);
  if (s < 3 * 86400)
    return fmt::format("{:.1f}h", s / 3600);
  if (s < 365.25 * 86400)
    return fmt::format("{:.1f}d", s / 86400);
  return fmt::format("{:.3g} years (check dem.dt and run.end_time)", s / (365.25 * 86400));
}

// A configuration or derived value as typed JSON: the text describe_scene and DerivedNumbers
// give (TOML numbers, "strings", [arrays], booleans) is JSON as well, so it is parsed; text that
// is not (a path with a backslash) stays a string.
inline nlohmann::ordered_json typed_value(const std::string& text) {
  auto v = nlohmann::ordered_json::parse(text, nullptr, false);
  return v.is_discarded() ? nlohmann::ordered_json(text) : v;
}

// The part of run.json every loop writes first: program, version, scene, the resolved
// configuration, derived numbers, ranks, threads and the particle count.
inline nlohmann::ordered_json run_json_header(const Scene& described, const std::string& name,
                                       const DerivedNumbers& derived, const ParallelEnv& env,
                                       std::size_t particles) {
  nlohmann::ordered_json j;
  j["program"] = "cfddem";
  j["version"] = CFDDEM_VERSION;
  j["scene"] = name;
  nlohmann::ordered_json cfg;
  for (const auto& [k, v] : describe_scene(described))
    cfg[k] = typed_value(v);
  j["configuration"] = cfg;
  nlohmann::ordered_json der;
  for (const auto& [k, v] : derived.table())
    der[k] = typed_value(v);
  j["derived"] = der;
  j["ranks"] = env.ranks();
  j["threads"] = env.threads();
  j["simd_level"] = std::string(simd_level_name(simd_level()));
  j["particles"] = particles;
  return j;
}

// phase_seconds: every timed phase, and the rest of the loop as "other".
inline nlohmann::ordered_json phase_json(const PhaseTimer& timer, double loop_seconds) {
  nlohmann::ordered_json ph;
  double timed = 0.0;
  for (const Phase p :
       {Phase::neighbor, Phase::regrid, Phase::force, Phase::integrate, Phase::comm, Phase::io,
        Phase::fluid, Phase::start}) {
    ph[std::string(phase_names[static_cast<int>(p)])] = timer.seconds(p);
    timed += timer.seconds(p);
  }
  ph["other"] = loop_seconds - timed;
  return ph;
}

// The work counters of a loop in run.json: particle steps, force evaluations (and what they
// count, when given), neighbor builds and the particle-step rate.
template <class Scheme>
// particle_steps_before: the count a restart took over from its checkpoint (the rate is this
// run's).
inline void add_work_counters(nlohmann::ordered_json& j, const Scheme& scheme, double loop_seconds,
                              const char* definition = nullptr,
                              std::int64_t particle_steps_before = 0) {
  j["particle_steps"] = scheme.particle_steps();
  j["force_evaluations"] = scheme.pair_evaluations();
  if (definition) j["force_evaluations_definition"] = definition;
  j["neighbor_builds"] = scheme.neighbor_builds();
  j["particle_steps_per_second"] =
      loop_seconds > 0
          ? static_cast<double>(scheme.particle_steps() - particle_steps_before) / loop_seconds
          : 0.0;
}

// run.json's rank_counts: per rank (arrays in rank order), the work it did and what it sent,
// for the scaling model (tools/scaling_model.py). Counts, not times: a function of the
// configuration and the rank count only. Collective: every rank calls it; rank 0 gets the
// object, the others an empty one. cell_updates: gas cells of this rank's box times gas
// sub-steps (0 without a gas).
inline nlohmann::ordered_json rank_counts_json(const Communicator& comm,
                                               std::int64_t particle_steps,
                                               std::int64_t force_evaluations,
                                               std::int64_t cell_updates) {
  const MessageCounts m = message_counts(); // before the gather below adds to it
  constexpr std::size_t kFields = 9;
  const std::array<std::int64_t, kFields> mine{particle_steps,     force_evaluations, cell_updates,
                                               m.p2p_messages,     m.p2p_bytes,       m.collectives,
                                               m.collective_bytes, m.reductions,
                                               m.orb_search_bytes};
  const std::vector<std::int64_t> all = comm.gather(std::span<const std::int64_t>(mine));
  nlohmann::ordered_json j;
  if (comm.rank() != 0) return j;
  static constexpr std::array<const char*, kFields> names = {
      "particle_steps", "force_evaluations", "cell_updates", "p2p_messages",
      "p2p_bytes",      "collectives",       "collective_bytes", "reductions",
      "orb_search_bytes"};
  for (std::size_t k = 0; k < kFields; ++k) {
    nlohmann::ordered_json v = nlohmann::ordered_json::array();
    for (std::size_t r = 0; r * kFields + k < all.size(); ++r) v.push_back(all[r * kFields + k]);
    j[names[k]] = v;
  }
  j["definition"] =
      "per rank, since this process started (set-up included, a restart starts from 0): owned "
      "particle steps; pair evaluations of its rows (a pair with a ghost counts on both ranks); "
      "gas cell updates (box cells x gas sub-steps); point-to-point sends and their bytes (halo, "
      "ghost and migration messages); collectives this rank took part in and its payload bytes; "
      "of those, the reductions, and the parallel ORB's median searches' bytes (its reductions' "
      "payload, part of collective_bytes). Not counted: snapshot and checkpoint I/O, hypre's own messages";
  return j;
}

} // namespace cfddem::apps
