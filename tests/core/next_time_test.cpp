// core/next_time.hpp: the next time of a recurring event, as summed and past tiny intervals.
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "core/next_time.hpp"

namespace {

using cfddem::next_time_after;

// A few intervals passed: the sum the loops always made, addition by addition.
TEST(NextTime, FewIntervalsAreSummedAsBefore) {
  const double interval = 1e-4 / 3.0;
  double summed = interval;
  while (summed <= 7e-4)
    summed += interval;
  EXPECT_EQ(next_time_after(interval, interval, 7e-4), summed);
  EXPECT_EQ(next_time_after(5e-3, interval, 7e-4), 5e-3); // already beyond t
}

// 1e-20 s against 1e-4 s (1e16 additions) and 1e-300 s (no addition moves the sum): a time
// beyond t, without the additions.
TEST(NextTime, IntervalsFarBelowTheStepJumpPastT) {
  for (const double interval : {1e-20, 1e-300, std::numeric_limits<double>::denorm_min()}) {
    const double t = 1e-4;
    const double next = next_time_after(interval, interval, t);
    EXPECT_GT(next, t) << interval;
    EXPECT_LE(next, t * (1 + 1e-12) + interval) << interval;
  }
}

} // namespace
