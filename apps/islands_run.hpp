// The islands scheme's adapter for the time loop (apps/scheme_runs.hpp): what it adds to the
// sub-iterated base (apps/subiterated_run.hpp): dem.nsubit = "auto" (the loop's step a control
// interval, its sub-iterations chosen by the scheme), checkpoints at any sub-iteration, and its
// islands in run.json.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "apps/checkpoint.hpp"
#include "apps/rank_parts.hpp"
#include "apps/subiterated_run.hpp"
#include "core/communicator.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_history.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/subiteration_length.hpp"

namespace cfddem::apps {

class IslandsRun : public SubiteratedRunBase<dem::IslandsScheme> {
public:
  static constexpr const char* kName = "islands";

  static ParticleStore particles(const Scene& scene, std::optional<Checkpoint>& ck,
                                 const Communicator& comm, const std::string& path, Restart& r) {
    auto* o = ck ? std::get_if<dem::IslandsScheme::State>(&ck->scheme_state) : nullptr;
    if (RankParts(comm).ranks && o && o->history.size() == 0 && !o->hx.empty()) {
      // A one-rank checkpoint's history per entry of its list: the records by ids the R-rank
      // scheme routes (the list itself is not restored there).
      o->history =
          dem::history_from_rows(ck->particles.id, o->offsets, o->neighbors, o->hx, o->hy, o->hz);
    }
    return SubiteratedRunBase::particles(scene, ck, comm, path, r);
  }

  using SubiteratedRunBase::SubiteratedRunBase;

  // The loop's step: a sub-iteration, or with dem.nsubit = "auto" a control interval.
  double dt() const { return scheme.auto_length() ? scheme.interval() : scheme.dt_sub(); }
  bool auto_length() const { return scheme.auto_length(); }
  // The sub-iterations of the next control interval ("auto" only).
  long long begin_interval() { return scheme.begin_interval(); }
  // The step past the end that completes the last row ("auto" only: the shortest it allows).
  void begin_completion() { scheme.begin_completion(); }
  long long checkpoint_every(long long every) const { return every; } // any sub-iteration

  std::string banner(long long n_end) const {
    if (auto_length())
      return fmt::format("islands scheme, dem.nsubit = \"auto\": dt_sp chosen per control "
                         "interval of {:.4e} s (first {:.4e} s; fine dt = {:.4e} s), {} intervals",
                         dt(), scheme.dt_sub(), scheme.dt_fine(), n_end);
    return fixed_banner(kName, "", n_end);
  }
  std::string progress(long long k, double frac, double, const std::string& eta) const {
    // "auto": k counts control intervals; the sub-iterations and the current count are shown.
    const std::string at = auto_length() ? fmt::format("sub-iteration {:>8} (nsubit {:>4})",
                                                       scheme.subiterations(), scheme.nsubit())
                                         : fmt::format("sub-iteration {:>8}", k);
    return progress_line(at, frac, "particles", eta);
  }
  void describe(nlohmann::ordered_json& j, const std::vector<std::vector<double>>&) const {
    j["dt"] = scheme.dt_fine();
    // "auto": the last choice (the step past the end is a short one).
    j["dt_sp"] = scheme.auto_length()
                     ? scheme.interval() / static_cast<double>(scheme.next_nsubit())
                     : scheme.dt_sub();
    describe_steps(j, parts_.ranks);
    describe_islands(j);
  }
  const char* phase_note() const {
    if (parts_.ranks)
      return "rank 0's phases; regrid: the parallel ORB and knapsack; neighbor: migration, "
             "ghosts, rows, speed bounds, "
             "links and islands (with their reductions); force: free flight, the local "
             "islands' tasks and the spanning islands' fine steps with their ghost "
             "refreshes";
    return "neighbor: speed bounds, links, islands and Verlet list builds; force: free "
           "flight and the islands' tasks (force and update)";
  }
  const char* force_definition() const {
    return parts_.ranks
               ? "pairs inside a fine island evaluated per local step, over all ranks (a pair "
                 "across ranks counted once)"
               : "neighbor-list pairs inside a fine island evaluated per local step (each "
                 "pair once)";
  }
  void describe_balance(nlohmann::ordered_json& j) const {
    describe_regrids(j, "parallel ORB + Hilbert knapsack at the first build after dem.nsubit "
                        "sub-iterations; migration, ghosts and rows at a build (when the rows "
                        "could miss a pair), not at every sub-iteration");
  }
  std::string performance(const PhaseTimer& t, double pss, double wait_max) const {
    const std::string spanning =
        parts_.ranks ? fmt::format("; spanning sub-iterations {} of {}; bound violations {}",
                                   scheme.spanning_subiterations(), scheme.subiterations(),
                                   scheme.bound_violations())
                     : std::string();
    return performance_line(t, pss, wait_max, "islands", "steps", spanning);
  }

private:
  // The islands' run.json entries: collisions its bound could have missed (none expected), the
  // dense sub-iterations, and the island sizes (one rank) or the islands across ranks (R ranks).
  void describe_islands(nlohmann::ordered_json& j) const {
    if (scheme.auto_length())
      describe_length(j);
    j["bound_violations"] = scheme.bound_violations();
    j["global_subiterations"] = scheme.global_subiterations();
    j["global_subiterations_definition"] =
        "sub-iterations where every particle took the fine steps together (the explicit "
        "scheme's work): more than a quarter of the particles were linked (a dense bed), or "
        "dem.nsubit = \"auto\" chose the global mode for the interval";
    if (parts_.ranks) {
      const auto subits = static_cast<double>(std::max<std::int64_t>(1, scheme.subiterations()));
      j["spanning_subiterations"] = scheme.spanning_subiterations();
      j["spanning_subiteration_fraction"] =
          static_cast<double>(scheme.spanning_subiterations()) / subits;
      j["spanning_particles_mean"] = static_cast<double>(scheme.spanning_particles()) / subits;
      j["spanning_island_parts"] = scheme.spanning_island_parts();
      j["spanning_definition"] =
          "islands with members on more than one rank: sub-iterations with at least one "
          "(outside the dense mode), their member particles per sub-iteration (mean), and their "
          "parts summed over ranks and sub-iterations; they take the fine steps together with a "
          "ghost refresh per fine step";
      j["expired_builds"] = scheme.expired_builds();
      j["expired_builds_definition"] =
          "builds (of neighbor_builds) made inside a sub-iteration because two particles' "
          "reaches (displacement since the last build + speed bound x dt_sp) could add up to "
          "the skin";
    } else {
      nlohmann::ordered_json hist;
      const auto h = scheme.island_size_histogram();
      for (std::size_t b = 0; b < h.size(); ++b)
        if (h[b] > 0)
          hist[b == 0   ? std::string("1")
               : b == 1 ? std::string("2")
                        : fmt::format("{}-{}", (1LL << (b - 1)) + 1, 1LL << b)] = h[b];
      j["island_sizes"] = hist;
      const auto d = scheme.fine_fraction_distribution();
      j["fine_fraction_per_particle"] = {{"mean", d[0]}, {"min", d[1]}, {"p10", d[2]},
                                         {"p50", d[3]},  {"p90", d[4]}, {"p99", d[5]},
                                         {"max", d[6]}};
      j["fine_fraction_per_particle_definition"] =
          "distribution over particles of the fraction of sub-iterations each spent in a fine "
          "island";
      j["island_sizes_definition"] = "islands of each size, one count per island per "
                                     "sub-iteration (size 1: lone particles in free flight, or "
                                     "tied to a wall)";
    }
  }
  // dem.nsubit = "auto": every choice of the sub-iteration length with its reason.
  void describe_length(nlohmann::ordered_json& j) const {
    j["nsubit"] = "auto";
    j["control_interval"] = scheme.interval();
    nlohmann::ordered_json rows = nlohmann::ordered_json::array();
    const auto& log = scheme.choices();
    const auto& cols = dem::IslandsScheme::kChoiceColumns;
    for (std::size_t r = 0; r + cols.size() <= log.size(); r += cols.size()) {
      nlohmann::ordered_json row;
      for (std::size_t c = 0; c < cols.size(); ++c) {
        const double v = log[r + c];
        if (c == 1 || c == 3 || c == 4 || c == 5)
          row[cols[c]] = static_cast<long long>(v);
        else if (c + 1 == cols.size())
          row[cols[c]] = dem::length::reason_text(static_cast<int>(v));
        else
          row[cols[c]] = v;
      }
      rows.push_back(row);
    }
    j["nsubit_choices"] = rows;
    j["nsubit_choices_definition"] =
        "dem.nsubit = \"auto\": a row per change of the sub-iterations per control interval "
        "(dem.regrid_interval, with a gas fluid.dt), chosen at the end of an interval for the "
        "next from operation counts (docs/schemes.md): t when chosen, nsubit, dt_sp, the "
        "intervals it was kept for, the bounds it was chosen within (nsubit_min: the skin or "
        "the gas force's change; nsubit_max: dt_sp at least the fine step), the fine particles "
        "the model expected per sub-iteration, rho (fine particles measured / first-contact "
        "count), the modelled cost ratio to the previous nsubit, and the reason";
    if (scheme.gas_change_ratio_max() > 0.0) {
      j["gas_force_change_ratio_max"] = scheme.gas_change_ratio_max();
      j["gas_force_change_bound"] = dem::length::kGasChangeBound;
      j["gas_force_change_definition"] =
          "largest change of a held gas acceleration over one sub-iteration (at the rate it "
          "changed over its fluid step) / the largest held acceleration (or |g|); \"auto\" keeps "
          "it within the bound unless dt_sp would fall below the fine step";
    }
  }
};

} // namespace cfddem::apps
