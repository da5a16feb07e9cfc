// The orb scheme's adapter for the time loop (apps/scheme_runs.hpp): what it adds to the
// sub-iterated base (apps/subiterated_run.hpp): a fixed dt_sp, checkpoints only where the ORB is
// rebuilt, its leaves in the banner and run.json.
#pragma once

#include <algorithm>
#include <cstddef>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/run_output.hpp"
#include "apps/subiterated_run.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::apps {

class OrbRun : public SubiteratedRunBase<dem::OrbScheme> {
public:
  static constexpr const char* kName = "orb";

  OrbRun(const Scene& scene, ParticleStore& p, const dem::ParticleRange& range,
         const Communicator& comm, PhaseTimer& timer, const dem::StepClock& step_clock)
      : SubiteratedRunBase(scene, p, range, comm, timer, step_clock),
        levels_(scene.partition.orb_levels) {}

  double dt() const { return scheme.dt_sub(); }
  bool auto_length() const { return false; }
  long long begin_interval() { return 1; }
  void begin_completion() {}
  // Checkpoints only at regrid points (multiples of dem.nsubit), where the ORB is rebuilt from
  // the store: the interval rounded up to whole regrid intervals.
  long long checkpoint_every(long long every) const {
    if (every > 0)
      return (every + scheme.nsubit() - 1) / scheme.nsubit() * scheme.nsubit();
    return every;
  }

  std::string banner(long long n_end) const {
    const int leaves = parts_.ranks ? scheme.leaf_count() : 1 << levels_;
    return fixed_banner(kName, fmt::format(": {} leaves", leaves), n_end);
  }
  std::string progress(long long k, double frac, double, const std::string& eta) const {
    return progress_line(fmt::format("sub-iteration {:>8}", k), frac, "leaves", eta);
  }
  void describe(nlohmann::ordered_json& j, const std::vector<std::vector<double>>& rows) const {
    j["dt"] = scheme.dt_fine();
    j["dt_sp"] = scheme.dt_sub();
    j["leaves"] = scheme.leaf_count();
    describe_steps(j, true);
    j["global_subiterations"] = scheme.global_subiterations();
    j["global_subiterations_definition"] =
        "sub-iterations where every particle took the fine steps together through the explicit "
        "scheme's passes (no friction, dem.orb_global; on R ranks from "
        "dem.orb_global_min_per_rank particles per rank): the leaves that would step finely held "
        "more than 3/4 of the particles over all ranks";
    if (parts_.ranks) {
      // The mean over the rows after the first (each closes an interval).
      const auto col = static_cast<std::size_t>(
          std::find(kBaseColumns.begin(), kBaseColumns.end(), "fine_leaf_fraction") -
          kBaseColumns.begin());
      double fine = 0.0;
      for (std::size_t r = 1; r < rows.size(); ++r)
        fine += rows[r][col];
      j["fine_leaf_fraction_mean"] =
          rows.size() > 1 ? fine / static_cast<double>(rows.size() - 1) : 0.0;
      j["fine_leaf_fraction_definition"] =
          "mean over the diagnostics rows of the fraction of (non-empty leaf, sub-iteration) "
          "pairs on the fine step, over all ranks";
    }
  }
  const char* phase_note() const {
    if (parts_.ranks)
      return "rank 0's phases; regrid: the parallel ORB and knapsack; neighbor: migration, "
             "ghost exchange and the rows; "
             "force: its leaves' local steps and the reductions that close a sub-iteration";
    return "regrid: ORB regrid and re-sort; neighbor: the candidate pairs and rows; force: the "
           "leaves' tasks (ghosts, local "
           "lists, force and update)";
  }
  const char* force_definition() const {
    return parts_.ranks ? "candidate pairs evaluated per local step, over all ranks: pairs within "
                          "a leaf once, pairs across a leaf boundary once per side (rows rebuilt "
                          "at every sub-iteration)"
                        : "candidate pairs evaluated per local step: pairs within a leaf once, "
                          "pairs across a leaf boundary once per side (each leaf evaluates its "
                          "side against the other's frozen copy)";
  }
  void describe_balance(nlohmann::ordered_json& j) const {
    describe_regrids(j, "parallel ORB + Hilbert knapsack every dem.regrid_interval (weights: "
                        "partition.weights); migration and ghosts at every sub-iteration");
  }
  std::string performance(const PhaseTimer& t, double pss, double wait_max) const {
    return performance_line(t, pss, wait_max, "regrid+resort", "leaves", "");
  }

private:
  int levels_;
};

} // namespace cfddem::apps
