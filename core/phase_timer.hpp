// Wall time accumulated per phase of the step loop (neighbor, force, integrate, I/O), for the
// LAMMPS-style breakdown in run.json. Cheap enough to wrap every step.
#pragma once

#include <array>
#include <chrono>
#include <string_view>

namespace cfddem {

enum class Phase { neighbor = 0, force, integrate, io, other, fluid, count };

inline constexpr std::array<std::string_view, static_cast<int>(Phase::count)> phase_names = {
    "neighbor", "force", "integrate", "io", "other", "fluid"};

class PhaseTimer {
public:
  using clock = std::chrono::steady_clock;
  void add(Phase p, clock::duration d) { seconds_[static_cast<int>(p)] += std::chrono::duration<double>(d).count(); }
  double seconds(Phase p) const { return seconds_[static_cast<int>(p)]; }

  // RAII: time a scope into a phase.
  class Scope {
  public:
    Scope(PhaseTimer& t, Phase p) : t_(t), p_(p), start_(clock::now()) {}
    ~Scope() { t_.add(p_, clock::now() - start_); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

  private:
    PhaseTimer& t_;
    Phase p_;
    clock::time_point start_;
  };

private:
  std::array<double, static_cast<int>(Phase::count)> seconds_{};
};

} // namespace cfddem
