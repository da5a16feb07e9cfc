// Wall time accumulated per phase of the step loop (neighbor, force, integrate, I/O), for the
// LAMMPS-style breakdown in run.json. Cheap enough to wrap every step.
#pragma once

#include <array>
#include <chrono>
#include <optional>
#include <string_view>

namespace cfddem {

// start: the scheme's start or restore and the gas's first deposition, once per run.
// regrid: a new decomposition (the ORB over the particles and the knapsack over ranks, the
// orb scheme's leaves on one rank); the migration and rows that follow are neighbor's.
// comm: a particle scheme's messages and waits outside its rebuilds (the explicit scheme's ghost
// forward and skin reduction after every step, on R ranks).
enum class Phase { neighbor = 0, force, integrate, io, other, fluid, start, regrid, comm, count };

inline constexpr std::array<std::string_view, static_cast<int>(Phase::count)> phase_names = {
    "neighbor", "force", "integrate", "io", "other", "fluid", "start", "regrid", "comm"};

class PhaseTimer {
public:
  using clock = std::chrono::steady_clock;
  void add(Phase p, clock::duration d) {
    seconds_[static_cast<int>(p)] += std::chrono::duration<double>(d).count();
  }
  double seconds(Phase p) const { return seconds_[static_cast<int>(p)]; }
  // The particles' rebuilds: neighbor with the regrids it starts (what neighbor alone counted
  // before regrid had a name of its own).
  double rebuild_seconds() const { return seconds(Phase::neighbor) + seconds(Phase::regrid); }

  // RAII: time a scope into a phase. Times are exclusive: a scope opened inside another (a list
  // rebuild inside the link rounds, say) pauses the enclosing one until it closes, so the
  // phases never count the same second twice and their sum stays within the loop's wall time.
  // Scopes nest on the thread that owns the timer only (none is opened inside a task).
  class Scope {
  public:
    Scope(PhaseTimer& t, Phase p) : t_(t), outer_(t.open_) {
      const auto now = clock::now();
      if (outer_)
        t_.add(*outer_, now - t_.since_);
      t_.open_ = p, t_.since_ = now;
    }
    ~Scope() {
      const auto now = clock::now();
      t_.add(*t_.open_, now - t_.since_);
      t_.open_ = outer_, t_.since_ = now;
    }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

  private:
    PhaseTimer& t_;
    std::optional<Phase> outer_;
  };

private:
  std::array<double, static_cast<int>(Phase::count)> seconds_{};
  std::optional<Phase> open_; // the innermost open scope's phase
  clock::time_point since_;   // when open_ last started or resumed
};

} // namespace cfddem
