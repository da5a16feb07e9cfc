// Which scheme's state a checkpoint holds, saved and restored by that scheme's own functions
// (dem/{explicit,orb,islands}_checkpoint.cpp).
#include "dem/scheme_checkpoint.hpp"

#include <string>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::dem {

const char* scheme_name(const SchemeState& s) {
  constexpr const char* kNames[] = {"explicit", "orb", "islands"};
  return kNames[s.index()];
}

void save(StateWriter& w, const SchemeState& s, const std::vector<std::int64_t>& ids) {
  if (const auto* e = std::get_if<ExplicitScheme::State>(&s)) {
    save(w, *e);
    return;
  }
  save(w, ExplicitScheme::State{}); // format 1: explicit's group in every checkpoint
  if (const auto* o = std::get_if<OrbScheme::State>(&s))
    save(w, *o, ids);
  else
    save(w, std::get<IslandsScheme::State>(s), ids);
}

std::vector<double> second_values(const OrbScheme::State& s) { return s.cost; }
void set_second_values(OrbScheme::State& s, std::vector<double> v) { s.cost = std::move(v); }

std::vector<double> second_values(const IslandsScheme::State& s) {
  return std::vector<double>(s.fine_subits.begin(), s.fine_subits.end());
}
void set_second_values(IslandsScheme::State& s, const std::vector<double>& v) {
  s.fine_subits.assign(v.size(), 0);
  for (std::size_t i = 0; i < v.size(); ++i)
    s.fine_subits[i] = static_cast<std::int64_t>(v[i]);
}

SchemeState restore_scheme(StateReader& r, std::string_view scheme,
                           const std::vector<std::int64_t>& ids) {
  ExplicitScheme::State e;
  restore(r, e); // in every checkpoint; orb's and islands' hold only empty lists
  if (scheme == "explicit")
    return e;
  if (scheme == "orb") {
    OrbScheme::State o;
    restore(r, o, ids);
    return o;
  }
  if (scheme == "islands") {
    IslandsScheme::State q;
    restore(r, q, ids);
    return q;
  }
  throw RunError(fmt::format("unknown scheme \"{}\"", scheme));
}

} // namespace cfddem::dem
