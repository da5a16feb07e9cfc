#include "dem/contact_history.hpp"

#include <algorithm>
#include <bit>
#include <numeric>

namespace cfddem::dem {

void ContactHistory::append(const ContactHistory& h) {
  owner.insert(owner.end(), h.owner.begin(), h.owner.end());
  partner.insert(partner.end(), h.partner.begin(), h.partner.end());
  hx.insert(hx.end(), h.hx.begin(), h.hx.end());
  hy.insert(hy.end(), h.hy.begin(), h.hy.end());
  hz.insert(hz.end(), h.hz.begin(), h.hz.end());
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
  if (off.empty() || hx.size() != nb.size()) return h; // never built, or built without history
  for (std::size_t i = 0; i < rows && i + 1 < off.size(); ++i)
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k)
      if (hx[k] != 0.0 || hy[k] != 0.0 || hz[k] != 0.0)
        h.add(p.id[i], p.id[nb[k]], hx[k], hy[k], hz[k]);
  return h;
}

void attach_history(ContactHistory h, const ParticleStore& p, const VerletList& list,
                    std::size_t rows, std::vector<double>& hx, std::vector<double>& hy,
                    std::vector<double>& hz) {
  const auto off = list.offsets();
  const auto nb = list.neighbors();
  hx.assign(nb.size(), 0.0), hy.assign(nb.size(), 0.0), hz.assign(nb.size(), 0.0);
  if (h.size() == 0) return;
  // Records sorted by (owner, partner): an owner's records are one range, found by bisection.
  std::vector<std::uint32_t> order(h.size());
  std::iota(order.begin(), order.end(), 0U);
  std::sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) {
    return h.owner[a] != h.owner[b] ? h.owner[a] < h.owner[b] : h.partner[a] < h.partner[b];
  });
  std::vector<std::int64_t> owner(h.size());
  for (std::size_t q = 0; q < h.size(); ++q) owner[q] = h.owner[order[q]];
  for (std::size_t i = 0; i < rows && i + 1 < off.size(); ++i) {
    if (off[i + 1] == off[i]) continue;
    const auto lo = std::lower_bound(owner.begin(), owner.end(), p.id[i]);
    const auto hi = std::upper_bound(lo, owner.end(), p.id[i]);
    if (lo == hi) continue;
    for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
      const std::int64_t j = p.id[nb[k]];
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

} // namespace cfddem::dem
