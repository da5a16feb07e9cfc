// Particles leaving or entering a run (an outflow face, apps/particle_outflow.hpp; an inlet,
// apps/particle_inlet.hpp): a scheme's saved state (one rank's, or one rank's canonical share)
// edited to the particles that stay and those that enter.
// - Leaving: compacted. A scheme rebuilt on the compacted store and restored from the compacted
//   state continues as if the removed particles had never been there: the pairs that stay keep
//   their neighbor-list entries and tangential history, the list keeps its reference positions
//   (no early rebuild), and every per-particle value moves with its particle.
// - Entering (appended at the end of the store): synchronised at the boundary (no half step
//   owed, no cost yet), and the neighbor list or candidate pairs are dropped for a rebuild at the
//   next step, the tangential history carried over by ids.
#pragma once

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <span>
#include <vector>

#include "dem/contact_history.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"

namespace cfddem::dem {

// Old index -> new index of a stable compaction of n particles to `kept` (increasing old
// indices); removed particles map to kGone.
class Compaction {
public:
  static constexpr std::uint32_t kGone = std::numeric_limits<std::uint32_t>::max();
  Compaction(std::size_t n, std::span<const std::uint32_t> kept);

  std::size_t before() const { return to_.size(); }
  std::span<const std::uint32_t> kept() const { return kept_; }
  std::uint32_t operator[](std::uint32_t old) const { return to_[old]; }

  // A per-particle array (size before(), or empty: left empty). Throws RunError otherwise.
  template <class T> void apply(std::vector<T>& v) const {
    if (v.empty())
      return;
    check_size(v.size());
    std::size_t k = 0;
    for (const std::uint32_t i : kept_)
      v[k++] = v[i];
    v.resize(k);
  }
  // Rows in CSR form (offsets of size before() + 1, or empty) with one value per entry in each of
  // `entries`: the rows and entries of removed particles go, partners are renumbered.
  void apply_rows(std::vector<std::uint32_t>& offsets, std::vector<std::uint32_t>& neighbors,
                  std::initializer_list<std::vector<double>*> entries) const;
  // Pairs (a[k], b[k]) of old indices: those with a removed member go, the rest are renumbered.
  void apply_pairs(std::vector<std::uint32_t>& a, std::vector<std::uint32_t>& b) const;
  // History records by particle id: those of a removed particle (`ids`: the old store's ids) go.
  void apply_history(ContactHistory& h, std::span<const std::int64_t> ids) const;

private:
  void check_size(std::size_t n) const;
  std::vector<std::uint32_t> to_;
  std::vector<std::uint32_t> kept_;
};

// One-rank states (the R-rank canonical states hold no list; they are not edited this way).
// `ids`: the store's ids before the compaction.
void erase_removed(ExplicitScheme::State& s, const Compaction& c);
void erase_removed(OrbScheme::State& s, const Compaction& c, std::span<const std::int64_t> ids);
void erase_removed(IslandsScheme::State& s, const Compaction& c, std::span<const std::int64_t> ids);

// Particles appended to the store after the `ids.size()` there (`ids`: their ids, in the store's
// order), at positions x, y, z (one per new particle). One signature for every scheme, each
// reading what its state needs.
void admit(ExplicitScheme::State& s, std::span<const std::int64_t> ids, std::span<const double> x,
           std::span<const double> y, std::span<const double> z);
void admit(OrbScheme::State& s, std::span<const std::int64_t> ids, std::span<const double> x,
           std::span<const double> y, std::span<const double> z);
void admit(IslandsScheme::State& s, std::span<const std::int64_t> ids, std::span<const double> x,
           std::span<const double> y, std::span<const double> z);

} // namespace cfddem::dem
