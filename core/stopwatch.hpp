// Adds the wall time of a scope to a running sum of seconds: the by-part timings of run.json
// (fluid_phase_seconds, the gas routing's seconds).
#pragma once

#include <chrono>

namespace cfddem {

class Stopwatch {
public:
  explicit Stopwatch(double& sum) : sum_(sum), t0_(std::chrono::steady_clock::now()) {}
  ~Stopwatch() {
    sum_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
  }
  Stopwatch(const Stopwatch&) = delete;
  Stopwatch& operator=(const Stopwatch&) = delete;

private:
  double& sum_;
  std::chrono::steady_clock::time_point t0_;
};

} // namespace cfddem
