// The explicit scheme's checkpoint: the neighbour list as built (rows, reference positions, the
// tangential history per entry) under /neighbor_list, the counters as root attributes.
#include "dem/scheme_checkpoint.hpp"

namespace cfddem::dem {

void save(StateWriter& w, const ExplicitScheme::State& s) {
  w.group("/neighbor_list");
  w.put("/neighbor_list/offsets", s.offsets);
  w.put("/neighbor_list/neighbors", s.neighbors);
  put_xyz(w, "/neighbor_list/", "_ref", s.x_ref, s.y_ref, s.z_ref);
  put_xyz(w, "/neighbor_list/history_", "", s.hx, s.hy, s.hz);
  w.attribute("skin", s.skin);
  w.attribute("need_rebuild", static_cast<std::int64_t>(s.need_rebuild));
  w.attribute("steps_taken", s.steps);
  w.attribute("particle_steps", s.particle_steps);
  w.attribute("pair_evaluations", s.pair_evaluations);
  w.attribute("neighbor_builds", s.builds);
}

void restore(StateReader& r, ExplicitScheme::State& s) {
  s.offsets = r.uint32s("/neighbor_list/offsets", StateReader::kAny);
  s.neighbors = r.uint32s("/neighbor_list/neighbors", StateReader::kAny);
  read_xyz(r, "/neighbor_list/", "_ref", StateReader::kAny, s.x_ref, s.y_ref, s.z_ref);
  read_xyz(r, "/neighbor_list/history_", "", StateReader::kAny, s.hx, s.hy, s.hz);
  s.skin = r.attribute_double("skin");
  s.need_rebuild = r.attribute_int64("need_rebuild") != 0;
  s.steps = r.attribute_int64("steps_taken");
  s.particle_steps = r.attribute_int64("particle_steps");
  s.pair_evaluations = r.attribute_int64("pair_evaluations");
  s.builds = r.attribute_int64("neighbor_builds");
}

} // namespace cfddem::dem
