// Each scheme's state in a checkpoint, in the scheme's own words: the names and layout are the
// scheme's (checkpoint format 1), the file is apps/'s. A checkpoint holds one SchemeState, the
// state of the scheme that wrote it; apps/ saves and restores it without knowing its insides. `ids`: the checkpoint's particle ids in
// the file's order, over which a tangential history is stored as rows. A restore throws
// RunError when an array does not fit.
#pragma once

#include <cstdint>
#include <string_view>
#include <variant>
#include <vector>

#include "core/state_io.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::dem {

// The state of the scheme that wrote a checkpoint (explicit: also the default, empty state).
using SchemeState = std::variant<ExplicitScheme::State, OrbScheme::State, IslandsScheme::State>;

// The scheme's name in a checkpoint's "scheme" attribute.
const char* scheme_name(const SchemeState& s);
// Format 1's layout: explicit's list and counters in every checkpoint (empty ones from orb and
// islands), then the sub-iterated scheme's own group.
void save(StateWriter& w, const SchemeState& s, const std::vector<std::int64_t>& ids);
// The state `scheme` wrote; throws RunError for a scheme this version does not know.
SchemeState restore_scheme(StateReader& r, std::string_view scheme,
                           const std::vector<std::int64_t>& ids);

// A sub-iterated scheme's per-particle value besides the half step (orb: the cost; islands: the
// fine-sub-iteration count, below 2^53, carried as a double), which a checkpoint on R ranks
// gathers in id order and shares out again at a restart.
std::vector<double> second_values(const OrbScheme::State& s);
void set_second_values(OrbScheme::State& s, std::vector<double> v);
std::vector<double> second_values(const IslandsScheme::State& s);
void set_second_values(IslandsScheme::State& s, const std::vector<double>& v);

// The state of type `State` held in `s`, made (empty) when `s` holds another scheme's: for the
// scheme's own adapter, which fills or reads it.
template <class State> State& state_of(SchemeState& s) {
  if (!std::holds_alternative<State>(s))
    s.template emplace<State>();
  return std::get<State>(s);
}

// Written for every scheme (its counters and an empty list from the sub-iterated ones).
void save(StateWriter& w, const ExplicitScheme::State& s);
void restore(StateReader& r, ExplicitScheme::State& s);

void save(StateWriter& w, const OrbScheme::State& s, const std::vector<std::int64_t>& ids);
void restore(StateReader& r, OrbScheme::State& s, const std::vector<std::int64_t>& ids);

void save(StateWriter& w, const IslandsScheme::State& s, const std::vector<std::int64_t>& ids);
void restore(StateReader& r, IslandsScheme::State& s, const std::vector<std::int64_t>& ids);

} // namespace cfddem::dem
