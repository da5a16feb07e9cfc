// The phase timer's scopes are exclusive: a scope opened inside another pauses it, so no second
// is counted twice and the phases never sum past the wall time around them.
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "core/phase_timer.hpp"

namespace cfddem {
namespace {

using namespace std::chrono_literals;

double since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

TEST(PhaseTimer, NestedScopePausesTheEnclosingPhase) {
  PhaseTimer timer;
  const auto t0 = std::chrono::steady_clock::now();
  double inner_wall = 0.0;
  {
    PhaseTimer::Scope outer(timer, Phase::neighbor);
    std::this_thread::sleep_for(5ms);
    const auto t1 = std::chrono::steady_clock::now();
    {
      PhaseTimer::Scope inner(timer, Phase::force);
      std::this_thread::sleep_for(20ms);
    }
    inner_wall = since(t1);
    std::this_thread::sleep_for(5ms);
  }
  const double wall = since(t0);
  const double nb = timer.seconds(Phase::neighbor), fc = timer.seconds(Phase::force);
  // Every clock read of the scopes lies between t0 and the last read: the exclusive phases
  // partition a part of that interval. Counted inclusively, the outer phase alone would hold
  // the inner 20 ms again and the sum would pass the wall time.
  EXPECT_LE(nb + fc, wall);
  EXPECT_GE(fc, 0.020);
  EXPECT_LE(fc, inner_wall);
  EXPECT_GE(nb, 0.010);
  EXPECT_LE(nb, wall - fc);
}

TEST(PhaseTimer, SamePhaseNestedCountsOnce) {
  PhaseTimer timer;
  const auto t0 = std::chrono::steady_clock::now();
  {
    PhaseTimer::Scope a(timer, Phase::neighbor);
    PhaseTimer::Scope b(timer, Phase::neighbor);
    std::this_thread::sleep_for(10ms);
  }
  const double wall = since(t0);
  EXPECT_GE(timer.seconds(Phase::neighbor), 0.010);
  EXPECT_LE(timer.seconds(Phase::neighbor), wall);
}

} // namespace
} // namespace cfddem
