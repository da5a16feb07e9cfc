// The next time of an event that recurs at a simulated-time interval (rows, snapshots,
// checkpoints, gas regrids), past a time t.
#pragma once

#include <cmath>
#include <limits>

namespace cfddem {

// The first multiple of interval beyond t, counting t within `slack` intervals below a multiple
// as at it; the double after t where that multiple rounds onto t, or where the count of
// intervals overflows (a denormal interval): the event then comes at every step.
inline double multiple_after(double t, double interval, double slack = 0.0) {
  const double multiple = (std::floor(t / interval + slack) + 1.0) * interval;
  return multiple > t && std::isfinite(multiple)
             ? multiple
             : std::nextafter(t, std::numeric_limits<double>::infinity());
}

// The first of next, next + interval, next + 2 interval, ... beyond t, summed as the event times
// always were while at most 65,536 intervals are passed (the times stay as they were, bit for
// bit, also when a restart sums them again up to its time). An interval far below the step
// (1e-20 s against a fluid step of 1e-4 s: 1e16 additions, and at 1e-300 s none that moves the
// sum: a run that never ended) jumps to multiple_after(t) instead.
inline double next_time_after(double next, double interval, double t) {
  constexpr long kSummed = 1L << 16;
  for (long n = 0; next <= t; ++n) {
    if (n == kSummed)
      return multiple_after(t, interval);
    next += interval;
  }
  return next;
}

} // namespace cfddem
