// The tangential spring history of frictional contacts keyed by particle ids, not list entries:
// the form in which it survives what renumbers the store (a migration to another rank, a
// checkpoint) and is reattached to a freshly built Verlet list, as ExplicitScheme carries it
// across a rebuild (an entry keeps its value when the pair (id_i, id_j) is listed again).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/particle_exchange.hpp"
#include "core/particle_store.hpp"
#include "dem/verlet_list.hpp"

namespace cfddem::dem {

// One record per (owner, partner) entry of the owner's row: the displacement xi the owner's
// contact force reads (docs/theory.md §2). The partner's row holds its own record.
struct ContactHistory {
  std::vector<std::int64_t> owner, partner;
  std::vector<double> hx, hy, hz;

  std::size_t size() const { return owner.size(); }
  void add(std::int64_t o, std::int64_t q, double x, double y, double z) {
    owner.push_back(o), partner.push_back(q), hx.push_back(x), hy.push_back(y), hz.push_back(z);
  }
  void append(const ContactHistory& h);
  // Adds the partner's record (partner, owner, -xi) of each record whose pair has none, as a
  // full list holds it (each side's spring is the other's negated, bit for bit).
  void add_mirrors();
  // Records as 5 doubles each (the ids as their bits), for ParticleExchange::route, and back.
  std::vector<double> pack() const;
  static ContactHistory unpack(std::span<const double> records);
  static constexpr int kStride = 5;
};

// The non-zero history of rows [0, rows) of `list` (hx, hy, hz: one value per list entry); an
// entry left at zero is what a new entry starts from, so it need not be kept. A half list's entry
// gives both records, the partner's too when the partner is one of the rows (a ghost's owner
// keeps its own).
ContactHistory collect_history(const ParticleStore& p, const VerletList& list, std::size_t rows,
                               std::span<const double> hx, std::span<const double> hy,
                               std::span<const double> hz);

// History per entry of `list` (rows [0, rows) of the store `p`): the record of (id_i, id_j)
// where `h` has one, zero elsewhere. Records whose pair is not listed are dropped (the pair
// separated beyond the list's reach: out of contact, so its history is zero anyway).
void attach_history(ContactHistory h, const ParticleStore& p, const VerletList& list,
                    std::size_t rows, std::vector<double>& hx, std::vector<double>& hy,
                    std::vector<double>& hz);

// The same over any rows (offsets `off`, partners `nb` as indices into `ids`, rows [0, rows)):
// the orb and islands schemes' rows, whose particle ids are given as a column (`ids[i]` is the
// id of row i and of partner index i).
ContactHistory collect_history(std::span<const std::int64_t> ids,
                               std::span<const std::uint32_t> off,
                               std::span<const std::uint32_t> nb, std::size_t rows,
                               std::span<const double> hx, std::span<const double> hy,
                               std::span<const double> hz);
void attach_history(ContactHistory h, std::span<const std::int64_t> ids,
                    std::span<const std::uint32_t> off, std::span<const std::uint32_t> nb,
                    std::size_t rows, std::vector<double>& hx, std::vector<double>& hy,
                    std::vector<double>& hz);

// Migration on R ranks: each record of `held` whose owner is one of the particles [0, owned) of
// `p` goes to the rank that particle moves to (dest[i]); returns the records this rank receives.
// Records of particles this rank does not hold (a restart's, of other ranks' shares) are dropped:
// their holder routes them. `moved` gains the records that leave this rank. Collective.
ContactHistory route_history(const ContactHistory& held, const ParticleStore& p, std::size_t owned,
                             std::span<const int> dest, ParticleExchange& exchange, int rank,
                             std::int64_t& moved);

// A checkpoint's form: rows over the particles `ids` (the checkpoint's order), entries naming
// the partner by its index there, one history value per entry: the layout of a serial
// ExplicitScheme::State's list and history, so either kind of checkpoint reads the same way.
struct HistoryRows {
  std::vector<std::uint32_t> offsets, neighbors;
  std::vector<double> hx, hy, hz;
};
// Throws RunError for a record naming an id that `ids` does not hold.
HistoryRows history_rows(const ContactHistory& h, std::span<const std::int64_t> ids);
// The records of rows saved over `ids` (no rows: none). Throws RunError when they do not fit.
ContactHistory history_from_rows(std::span<const std::int64_t> ids,
                                 std::span<const std::uint32_t> offsets,
                                 std::span<const std::uint32_t> neighbors,
                                 std::span<const double> hx, std::span<const double> hy,
                                 std::span<const double> hz);

} // namespace cfddem::dem
