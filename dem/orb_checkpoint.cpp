// The orb scheme's checkpoint under /orb: per particle the half step and the cost, the leaves'
// step counts, the counters (the global sub-iterations apart), the candidate pairs with their
// reference positions, and with friction the tangential history as rows over the checkpoint's
// particles.
#include "dem/history_checkpoint.hpp"
#include "dem/scheme_checkpoint.hpp"

namespace cfddem::dem {

void save(StateWriter& w, const OrbScheme::State& o, const std::vector<std::int64_t>& ids) {
  w.group("/orb");
  w.put("/orb/half_step", o.hprev);
  w.put("/orb/cost", o.cost);
  w.put("/orb/leaf_steps", o.leaf_steps);
  w.put("/orb/counters",
        std::vector<std::int64_t>{o.fine_count, o.leaf_subits, o.subits, o.particle_steps,
                                  o.pair_evaluations, o.builds, o.regrids, o.overlap_violations,
                                  o.retries, o.pairs_valid ? 1 : 0, o.prox_from_pairs ? 1 : 0});
  w.put("/orb/ratios", std::vector<double>{o.last_fine_fraction, o.max_overlap_ratio, o.skin});
  // Its own entry, so that checkpoints written before the global mode still load (as 0).
  w.put("/orb/global_subiterations", std::vector<std::int64_t>{o.global_subits});
  // The same for the held global interval's contact candidates (OrbScheme::Pairs::contact_only).
  w.put("/orb/pairs_contact_only", std::vector<std::int64_t>{o.pairs_contact_only ? 1 : 0});
  if (o.global_hold) { // the held global interval's ORB
    w.put("/orb/held_cut_axis", o.cut_axis);
    w.put("/orb/held_cut_position", o.cut_position);
    w.put("/orb/held_leaf_owner", o.leaf_owner);
  }
  // Candidate pairs (store indices) and their reference positions.
  w.put("/orb/contact_a", o.ca);
  w.put("/orb/contact_b", o.cb);
  w.put("/orb/proximity_a", o.pa);
  w.put("/orb/proximity_b", o.pb);
  put_xyz(w, "/orb/", "_ref", o.x_ref, o.y_ref, o.z_ref);
  save_history(w, "/orb", o.history, ids);
  if (!o.clock.empty()) // an adaptive fluid.dt: the time base of the sub-iterations
    w.put("/orb/interval_clock", o.clock);
}

void restore(StateReader& r, OrbScheme::State& o, const std::vector<std::int64_t>& ids) {
  const std::size_t n = ids.size();
  o.hprev = r.doubles("/orb/half_step", n);
  o.cost = r.doubles("/orb/cost", n);
  o.leaf_steps = r.int64s("/orb/leaf_steps", StateReader::kAny);
  const auto k = r.int64s("/orb/counters", 11);
  o.fine_count = k[0], o.leaf_subits = k[1], o.subits = k[2], o.particle_steps = k[3];
  o.pair_evaluations = k[4], o.builds = k[5], o.regrids = k[6], o.overlap_violations = k[7];
  o.retries = k[8], o.pairs_valid = k[9] != 0, o.prox_from_pairs = k[10] != 0;
  const auto q = r.doubles("/orb/ratios", 3);
  o.last_fine_fraction = q[0], o.max_overlap_ratio = q[1], o.skin = q[2];
  if (r.exists("/orb/global_subiterations"))
    o.global_subits = r.int64s("/orb/global_subiterations", 1)[0];
  if (r.exists("/orb/pairs_contact_only"))
    o.pairs_contact_only = r.int64s("/orb/pairs_contact_only", 1)[0] != 0;
  o.global_hold = r.exists("/orb/held_cut_axis");
  if (o.global_hold) {
    o.cut_axis = r.int64s("/orb/held_cut_axis", StateReader::kAny);
    o.cut_position = r.doubles("/orb/held_cut_position", o.cut_axis.size());
    o.leaf_owner = r.int64s("/orb/held_leaf_owner", StateReader::kAny);
  }
  o.ca = r.uint32s("/orb/contact_a", StateReader::kAny);
  o.cb = r.uint32s("/orb/contact_b", o.ca.size());
  o.pa = r.uint32s("/orb/proximity_a", StateReader::kAny);
  o.pb = r.uint32s("/orb/proximity_b", o.pa.size());
  read_xyz(r, "/orb/", "_ref", StateReader::kAny, o.x_ref, o.y_ref, o.z_ref);
  o.history = restore_history(r, "/orb", ids);
  if (r.exists("/orb/interval_clock"))
    o.clock = r.doubles("/orb/interval_clock", 2);
}

} // namespace cfddem::dem
