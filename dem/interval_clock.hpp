// The time of a sub-iterated scheme (orb, islands) whose sub-iteration length dt_sp may change
// at a fluid-step boundary (an adaptive fluid.dt: dt_sp = dt_f / dem.nsubit, dt_f chosen per
// step). The time is the time at the last change plus the sub-iterations since, at the length
// in force. With one length for the whole run (a fixed fluid.dt, or no gas) the base stays at
// (0 s, 0) and the time is subits x dt_sp bit for bit, as it was before lengths could change.
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::dem {

struct IntervalClock {
  double t_base = 0.0;          // the time at the last change of dt_sp
  std::int64_t subits_base = 0; // the sub-iterations taken then
  bool variable = false;        // a change happened (the base is state to checkpoint)

  double time(std::int64_t subits, double dt_sp) const {
    return t_base + static_cast<double>(subits - subits_base) * dt_sp;
  }
  // A new length starts after `subits` sub-iterations of `dt_sp_old`.
  void change_at(std::int64_t subits, double dt_sp_old) {
    t_base = time(subits, dt_sp_old);
    subits_base = subits;
    variable = true;
  }
  // dt_sp becomes `next` after `subits` sub-iterations (the base moves there). The length a
  // scheme was built with, before any change, changes nothing: the clock stays a fixed one.
  void set_length(std::int64_t subits, double& dt_sp, double next) {
    if (next == dt_sp && !variable)
      return;
    change_at(subits, dt_sp);
    dt_sp = next;
  }
  // The fluid step a scheme is handed (set_interval): a positive finite length, else RunError
  // naming the scheme.
  static void check_interval(double interval, const char* scheme) {
    if (!(interval > 0.0) || !std::isfinite(interval))
      throw RunError(fmt::format("{}: fluid step {} s is not a positive length", scheme, interval));
  }
  // The checkpoint's record after `subits` sub-iterations of `dt_sp`: the base moved to now, so
  // that a restored clock needs no dt_sp (the next change_at() computes the same base as a run
  // that went on: time(subits) is the saved base either way). Empty for one length: checkpoints
  // of fixed-step runs are unchanged.
  std::vector<double> saved(std::int64_t subits, double dt_sp) const {
    return variable ? std::vector<double>{time(subits, dt_sp), static_cast<double>(subits)}
                    : std::vector<double>{};
  }
  // Returns false if `v` is neither empty nor a saved base.
  bool restore(const std::vector<double>& v) {
    if (v.empty()) {
      *this = IntervalClock{};
      return true;
    }
    if (v.size() != 2 || !(v[1] >= 0.0))
      return false;
    t_base = v[0], subits_base = static_cast<std::int64_t>(v[1]), variable = true;
    return true;
  }
};

} // namespace cfddem::dem
