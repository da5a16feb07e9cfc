#include "dem/contact_history.hpp"

#include <algorithm>
#include <bit>
#include <numeric>
#include <unordered_map>
#include <utility>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::dem {

void ContactHistory::append(const ContactHistory& h) {
  owner.insert(owner.end(), h.owner.begin(), h.owner.end());
  partner.insert(partner.end(), h.partner.begin(), h.partner.end());
  hx.insert(hx.end(), h.hx.begin(), h.hx.end());
  hy.insert(hy.end(), h.hy.begin(), h.hy.end());
  hz.insert(hz.end(), h.hz.begin(), h.hz.end());
}

void ContactHistory::add_mirrors() {
  std::vector<std::pair<std::int64_t, std::int64_t>> have(size());
  for (std::size_t q = 0; q < size(); ++q)
    have[q] = {owner[q], partner[q]};
  std::sort(have.begin(), have.end());
  const std::size_t n = size();
  for (std::size_t q = 0; q < n; ++q)
    if (!std::binary_search(have.begin(), have.end(), std::pair{partner[q], owner[q]}))
      add(partner[q], owner[q], -hx[q], -hy[q], -hz[q]);
}

std::vector<double> ContactHistory::pack() const {
  std::vector<double> out;
  out.reserve(size() * kStride);
  for (std::size_t q = 0; q < size(); ++q) {
    out.push_back(std::bit_cast<double>(owner[q]));
    out.push_back(std::bit_cast<double>(partner[q]));
    out.push_back(hx[q]), out.push_back(hy[q]), out.push_back(hz[q]);
  }
  return out;
}

ContactHistory ContactHistory::unpack(std::span<const double> records) {
  ContactHistory h;
  for (std::size_t q = 0; q + kStride <= records.size(); q += kStride)
    h.add(std::bit_cast<std::int64_t>(records[q]), std::bit_cast<std::int64_t>(records[q + 1]),
          records[q + 2], records[q + 3], records[q + 4]);
  return h;
}

ContactHistory collect_history(const ParticleStore& p, const VerletList& list, std::size_t rows,
                               std::span<const double> hx, std::span<const double> hy,
                               std::span<const double> hz) {
  ContactHistory h;
  const auto off = list.offsets();
  const auto nb = list.neighbors();
  if (off.empty() || hx.size() != nb.size())
    return h; // never built, or built without history
  const bool half = list.kind() == RowKind::half;
  for (std::size_t i = 0; i < rows && i + 1 < off.size(); ++i)
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k)
      if (hx[k] != 0.0 || hy[k] != 0.0 || hz[k] != 0.0) {
        h.add(p.id[i], p.id[nb[k]], hx[k], hy[k], hz[k]);
        if (half && nb[k] < rows)
          h.add(p.id[nb[k]], p.id[i], -hx[k], -hy[k], -hz[k]);
      }
  return h;
}

// The same over rows given as spans, with the particle ids as a column (orb's rows: the
// scheme's own CSR arrays, not a VerletList).
ContactHistory collect_history(std::span<const std::int64_t> ids,
                               std::span<const std::uint32_t> off,
                               std::span<const std::uint32_t> nb, std::size_t rows,
                               std::span<const double> hx, std::span<const double> hy,
                               std::span<const double> hz) {
  ContactHistory h;
  if (off.empty() || hx.size() != nb.size())
    return h; // never built, or built without history
  for (std::size_t i = 0; i < rows && i + 1 < off.size(); ++i)
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k)
      if (hx[k] != 0.0 || hy[k] != 0.0 || hz[k] != 0.0)
        h.add(ids[i], ids[nb[k]], hx[k], hy[k], hz[k]);
  return h;
}

void attach_history(ContactHistory h, const ParticleStore& p, const VerletList& list,
                    std::size_t rows, std::vector<double>& hx, std::vector<double>& hy,
                    std::vector<double>& hz) {
  attach_history(std::move(h), p.id, list.offsets(), list.neighbors(), rows, hx, hy, hz);
}

void attach_history(ContactHistory h, std::span<const std::int64_t> ids,
                    std::span<const std::uint32_t> off, std::span<const std::uint32_t> nb,
                    std::size_t rows, std::vector<double>& hx, std::vector<double>& hy,
                    std::vector<double>& hz) {
  hx.assign(nb.size(), 0.0), hy.assign(nb.size(), 0.0), hz.assign(nb.size(), 0.0);
  if (h.size() == 0)
    return;
  // Records sorted by (owner, partner): an owner's records are one range, found by bisection.
  std::vector<std::uint32_t> order(h.size());
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return h.owner[a] != h.owner[b] ? h.owner[a] < h.owner[b] : h.partner[a] < h.partner[b];
  });
  std::vector<std::int64_t> owner(h.size());
  for (std::size_t q = 0; q < h.size(); ++q)
    owner[q] = h.owner[order[q]];
  for (std::size_t i = 0; i < rows && i + 1 < off.size(); ++i) {
    if (off[i + 1] == off[i])
      continue;
    const auto lo = std::lower_bound(owner.begin(), owner.end(), ids[i]);
    const auto hi = std::upper_bound(lo, owner.end(), ids[i]);
    if (lo == hi)
      continue;
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::int64_t j = ids[nb[k]];
      for (auto it = lo; it != hi; ++it) {
        const std::uint32_t q = order[static_cast<std::size_t>(it - owner.begin())];
        if (h.partner[q] == j) {
          hx[k] = h.hx[q], hy[k] = h.hy[q], hz[k] = h.hz[q];
          break;
        }
      }
    }
  }
}

ContactHistory route_history(const ContactHistory& held, const ParticleStore& p, std::size_t owned,
                             std::span<const int> dest, ParticleExchange& exchange, int rank,
                             std::int64_t& moved) {
  std::unordered_map<std::int64_t, std::uint32_t> index;
  index.reserve(owned);
  for (std::size_t i = 0; i < owned; ++i)
    index.emplace(p.id[i], static_cast<std::uint32_t>(i));
  ContactHistory mine;
  std::vector<int> to;
  for (std::size_t q = 0; q < held.size(); ++q) {
    const auto it = index.find(held.owner[q]);
    if (it == index.end())
      continue;
    mine.add(held.owner[q], held.partner[q], held.hx[q], held.hy[q], held.hz[q]);
    to.push_back(dest[it->second]);
    moved += to.back() != rank ? 1 : 0;
  }
  return ContactHistory::unpack(exchange.route(to, mine.pack(), ContactHistory::kStride));
}

HistoryRows history_rows(const ContactHistory& h, std::span<const std::int64_t> ids) {
  std::unordered_map<std::int64_t, std::uint32_t> index;
  index.reserve(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i)
    index.emplace(ids[i], static_cast<std::uint32_t>(i));
  auto at = [&](std::int64_t id) {
    const auto it = index.find(id);
    if (it == index.end())
      throw RunError(fmt::format("contact history names particle {}, which is not saved", id));
    return it->second;
  };
  HistoryRows r;
  r.offsets.assign(ids.size() + 1, 0);
  for (const std::int64_t o : h.owner)
    ++r.offsets[at(o) + 1];
  std::partial_sum(r.offsets.begin(), r.offsets.end(), r.offsets.begin());
  std::vector<std::uint32_t> next(r.offsets.begin(), r.offsets.end() - 1);
  r.neighbors.resize(h.size()), r.hx.resize(h.size()), r.hy.resize(h.size()), r.hz.resize(h.size());
  for (std::size_t q = 0; q < h.size(); ++q) {
    const std::uint32_t k = next[at(h.owner[q])]++;
    r.neighbors[k] = at(h.partner[q]);
    r.hx[k] = h.hx[q], r.hy[k] = h.hy[q], r.hz[k] = h.hz[q];
  }
  return r;
}

ContactHistory history_from_rows(std::span<const std::int64_t> ids,
                                 std::span<const std::uint32_t> offsets,
                                 std::span<const std::uint32_t> neighbors,
                                 std::span<const double> hx, std::span<const double> hy,
                                 std::span<const double> hz) {
  ContactHistory h;
  if (offsets.empty())
    return h;
  const std::size_t n = ids.size(), m = neighbors.size();
  if (offsets.size() != n + 1 || offsets.front() != 0 || offsets.back() != m || hx.size() != m ||
      hy.size() != m || hz.size() != m)
    throw RunError("checkpoint: the contact history does not fit the particles");
  for (std::size_t i = 0; i < n; ++i) {
    if (offsets[i + 1] < offsets[i])
      throw RunError("checkpoint: the contact history offsets are not monotonic");
    for (std::uint32_t k = offsets[i]; k < offsets[i + 1]; ++k) {
      if (neighbors[k] >= n)
        throw RunError("checkpoint: a contact partner is out of range");
      if (hx[k] != 0.0 || hy[k] != 0.0 || hz[k] != 0.0)
        h.add(ids[i], ids[neighbors[k]], hx[k], hy[k], hz[k]);
    }
  }
  return h;
}

} // namespace cfddem::dem
