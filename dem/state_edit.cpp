#include "dem/state_edit.hpp"

#include <algorithm>
#include <unordered_set>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem::dem {

Compaction::Compaction(std::size_t n, std::span<const std::uint32_t> kept)
    : to_(n, kGone), kept_(kept.begin(), kept.end()) {
  for (std::size_t k = 0; k < kept_.size(); ++k) {
    if (kept_[k] >= n || (k > 0 && kept_[k] <= kept_[k - 1]))
      throw std::invalid_argument("Compaction: kept indices must increase and lie below n");
    to_[kept_[k]] = static_cast<std::uint32_t>(k);
  }
}

void Compaction::check_size(std::size_t n) const {
  if (n != to_.size())
    throw RunError(fmt::format("particle removal: a per-particle array holds {} values for {} "
                               "particles",
                               n, to_.size()));
}

void Compaction::apply_rows(std::vector<std::uint32_t>& offsets,
                            std::vector<std::uint32_t>& neighbors,
                            std::initializer_list<std::vector<double>*> entries) const {
  if (offsets.empty())
    return;
  check_size(offsets.size() - 1);
  for (const auto* e : entries)
    if (!e->empty() && e->size() != neighbors.size())
      throw RunError("particle removal: the history does not fit the neighbor list");
  std::vector<std::uint32_t> off{0};
  std::size_t w = 0; // entries are moved down in place: w never passes the read position
  for (const std::uint32_t i : kept_) {
    for (std::uint32_t e = offsets[i]; e < offsets[i + 1]; ++e) {
      const std::uint32_t j = to_[neighbors[e]];
      if (j == kGone)
        continue;
      neighbors[w] = j;
      for (auto* v : entries)
        if (!v->empty())
          (*v)[w] = (*v)[e];
      ++w;
    }
    off.push_back(static_cast<std::uint32_t>(w));
  }
  neighbors.resize(w);
  for (auto* v : entries)
    if (!v->empty())
      v->resize(w);
  offsets = std::move(off);
}

void Compaction::apply_pairs(std::vector<std::uint32_t>& a, std::vector<std::uint32_t>& b) const {
  std::size_t w = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    const std::uint32_t i = to_[a[k]], j = to_[b[k]];
    if (i == kGone || j == kGone)
      continue;
    a[w] = i, b[w] = j, ++w;
  }
  a.resize(w), b.resize(w);
}

void Compaction::apply_history(ContactHistory& h, std::span<const std::int64_t> ids) const {
  if (h.size() == 0)
    return;
  check_size(ids.size());
  std::unordered_set<std::int64_t> gone;
  for (std::size_t i = 0; i < ids.size(); ++i)
    if (to_[i] == kGone)
      gone.insert(ids[i]);
  ContactHistory out;
  for (std::size_t k = 0; k < h.size(); ++k)
    if (!gone.contains(h.owner[k]) && !gone.contains(h.partner[k]))
      out.add(h.owner[k], h.partner[k], h.hx[k], h.hy[k], h.hz[k]);
  h = std::move(out);
}

void erase_removed(ExplicitScheme::State& s, const Compaction& c) {
  c.apply_rows(s.offsets, s.neighbors, {&s.hx, &s.hy, &s.hz});
  c.apply(s.x_ref), c.apply(s.y_ref), c.apply(s.z_ref);
}

void erase_removed(OrbScheme::State& s, const Compaction& c, std::span<const std::int64_t> ids) {
  c.apply(s.hprev), c.apply(s.cost);
  c.apply_pairs(s.ca, s.cb), c.apply_pairs(s.pa, s.pb);
  c.apply(s.x_ref), c.apply(s.y_ref), c.apply(s.z_ref);
  c.apply_history(s.history, ids);
  s.global_hold = false; // the leaves' ranges change: the next regrid point cuts a new ORB
}

void erase_removed(IslandsScheme::State& s, const Compaction& c,
                   std::span<const std::int64_t> ids) {
  c.apply_rows(s.offsets, s.neighbors, {&s.hx, &s.hy, &s.hz});
  c.apply(s.x_ref), c.apply(s.y_ref), c.apply(s.z_ref);
  c.apply(s.hprev), c.apply(s.fine_subits);
  c.apply_history(s.history, ids);
}

void admit(ExplicitScheme::State& s, std::span<const std::int64_t>, std::span<const double> x,
           std::span<const double> y, std::span<const double> z) {
  if (s.offsets.empty()) // a canonical share: no list
    return;
  for (std::size_t k = 0; k < x.size(); ++k) {
    s.offsets.push_back(s.offsets.back()); // an empty row until the rebuild
    s.x_ref.push_back(x[k]), s.y_ref.push_back(y[k]), s.z_ref.push_back(z[k]);
  }
  s.need_rebuild = true; // the rebuild carries the history over by ids
}

void admit(OrbScheme::State& s, std::span<const std::int64_t>, std::span<const double> x,
           std::span<const double>, std::span<const double>) {
  const std::size_t n_new = x.size();
  s.hprev.insert(s.hprev.end(), n_new, 0.0);
  s.cost.insert(s.cost.end(), n_new, 0.0);
  s.pairs_valid = false, s.global_hold = false; // the next regrid point cuts a new ORB
  s.ca.clear(), s.cb.clear(), s.pa.clear(), s.pb.clear();
  s.x_ref.clear(), s.y_ref.clear(), s.z_ref.clear();
}

void admit(IslandsScheme::State& s, std::span<const std::int64_t> ids, std::span<const double> x,
           std::span<const double>, std::span<const double>) {
  const std::size_t n_new = x.size();
  s.hprev.insert(s.hprev.end(), n_new, 0.0);
  s.fine_subits.insert(s.fine_subits.end(), n_new, 0);
  if (s.offsets.empty())
    return;
  // One rank: the list goes (the next sub-iteration builds one), its history by ids stays.
  if (!s.hx.empty())
    s.history.append(collect_history(ids, s.offsets, s.neighbors, ids.size(), s.hx, s.hy, s.hz));
  s.offsets.clear(), s.neighbors.clear();
  s.x_ref.clear(), s.y_ref.clear(), s.z_ref.clear();
  s.hx.clear(), s.hy.clear(), s.hz.clear();
}

} // namespace cfddem::dem
