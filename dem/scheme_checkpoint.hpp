// Each scheme's state in a checkpoint, in the scheme's own words: the names and layout are the
// scheme's (checkpoint format 1), the file is apps/'s. `ids`: the checkpoint's particle ids in
// the file's order, over which a tangential history is stored as rows. A restore throws
// RunError when an array does not fit.
#pragma once

#include <cstdint>
#include <vector>

#include "core/state_io.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::dem {

// Written for every scheme (its counters and an empty list from the sub-iterated ones).
void save(StateWriter& w, const ExplicitScheme::State& s);
void restore(StateReader& r, ExplicitScheme::State& s);

void save(StateWriter& w, const OrbScheme::State& s, const std::vector<std::int64_t>& ids);
void restore(StateReader& r, OrbScheme::State& s, const std::vector<std::int64_t>& ids);

void save(StateWriter& w, const IslandsScheme::State& s, const std::vector<std::int64_t>& ids);
void restore(StateReader& r, IslandsScheme::State& s, const std::vector<std::int64_t>& ids);

} // namespace cfddem::dem
