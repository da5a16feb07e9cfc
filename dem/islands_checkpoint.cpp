// The islands scheme's checkpoint under /islands: the list (one rank) with its per-entry
// history, or with a communicator the history's records as rows over the checkpoint's particles;
// per particle the half step and the fine-sub-iteration count; the counters, and the parts only
// some runs have (R ranks' counters, the chosen skin, dem.nsubit = "auto"'s choice and log).
#include "dem/history_checkpoint.hpp"
#include "dem/scheme_checkpoint.hpp"

namespace cfddem::dem {

void save(StateWriter& w, const IslandsScheme::State& o, const std::vector<std::int64_t>& ids) {
  w.group("/islands");
  w.put("/islands/offsets", o.offsets);
  w.put("/islands/neighbors", o.neighbors);
  put_xyz(w, "/islands/", "_ref", o.x_ref, o.y_ref, o.z_ref);
  if (!o.hx.empty()) // friction: the tangential history per entry of the list
    put_xyz(w, "/islands/history_", "", o.hx, o.hy, o.hz);
  // history_offsets tells the two history forms apart at a restore.
  save_history(w, "/islands", o.history, ids);
  w.put("/islands/half_step", o.hprev);
  w.put("/islands/fine_subiterations", o.fine_subits);
  w.put("/islands/size_histogram", o.size_hist);
  w.put("/islands/counters", o.counters);
  w.put("/islands/ratios", std::vector<double>{o.skin, o.max_overlap_ratio, o.last_fine_fraction});
  if (!o.rank_counters.empty()) {
    w.put("/islands/rank_counters", o.rank_counters);
    w.put("/islands/rank_values", o.rank_values);
  }
  if (!o.skin_choice.empty())
    w.put("/islands/skin_choice", o.skin_choice);
  if (!o.length_counters.empty()) {
    w.put("/islands/length_counters", o.length_counters);
    w.put("/islands/length_values", o.length_values);
    w.put("/islands/length_choices", o.length_log);
  }
  if (!o.clock.empty()) // an adaptive fluid.dt: the intervals' time base or reference
    w.put("/islands/interval_clock", o.clock);
}

void restore(StateReader& r, IslandsScheme::State& o, const std::vector<std::int64_t>& ids) {
  const std::size_t n = ids.size();
  o.offsets = r.uint32s("/islands/offsets", StateReader::kAny);
  o.neighbors = r.uint32s("/islands/neighbors", StateReader::kAny);
  read_xyz(r, "/islands/", "_ref", StateReader::kAny, o.x_ref, o.y_ref, o.z_ref);
  if (r.exists("/islands/history_x") && !r.exists("/islands/history_offsets"))
    read_xyz(r, "/islands/history_", "", o.neighbors.size(), o.hx, o.hy, o.hz);
  o.history = restore_history(r, "/islands", ids);
  o.hprev = r.doubles("/islands/half_step", n);
  o.fine_subits = r.int64s("/islands/fine_subiterations", n);
  o.size_hist = r.int64s("/islands/size_histogram", StateReader::kAny);
  o.counters = r.int64s("/islands/counters", 12);
  const auto q = r.doubles("/islands/ratios", 3);
  o.skin = q[0], o.max_overlap_ratio = q[1], o.last_fine_fraction = q[2];
  if (r.exists("/islands/rank_counters")) {
    o.rank_counters = r.int64s("/islands/rank_counters", 6);
    o.rank_values = r.doubles("/islands/rank_values", 1);
  }
  if (r.exists("/islands/skin_choice")) // one rank, since the islands skin is chosen
    o.skin_choice = r.doubles("/islands/skin_choice", 4);
  if (r.exists("/islands/length_counters")) {
    // 8 counters (6 before the global mode's two flags: still read; the scheme checks).
    o.length_counters = r.int64s("/islands/length_counters", StateReader::kAny);
    o.length_values = r.doubles("/islands/length_values", StateReader::kAny);
    o.length_log = r.doubles("/islands/length_choices", StateReader::kAny);
  }
  if (r.exists("/islands/interval_clock"))
    o.clock = r.doubles("/islands/interval_clock", StateReader::kAny);
}

} // namespace cfddem::dem
