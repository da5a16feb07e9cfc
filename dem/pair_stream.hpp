// One part of a half Verlet list's rows laid out flat, pair by pair: the row particle i, the
// partner j and the list entry k of each pair, in row order, with the start of each fixed block
// of rows. The explicit scheme's pair pass (dem/verlet_passes.hpp) walks it as one long loop:
// with 2-3 partners per row in a dense gas, a loop per row ends at an unpredictable trip count,
// and that branch miss (about one per row) cost as much as the row's arithmetic. Built once per
// list build; the contacts found and their order are those of the rows, bit for bit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "dem/verlet_list.hpp"

namespace cfddem::dem {

struct PairStream {
  std::vector<std::uint32_t> i, j, k;
  // Pairs of block b: [block_start[b], block_start[b + 1]).
  std::vector<std::uint32_t> block_start;

  std::size_t blocks() const { return block_start.empty() ? 0 : block_start.size() - 1; }

  // The pairs of `rows` (increasing row indices of `list`), the part before wrap_begin() (Tail =
  // false) or from it (Tail = true), in blocks of `block` rows. `with_entry`: keep k too (the
  // tangential history is stored per list entry). Upper: keep only partners of higher index, so
  // that a full list's rows give each pair once, as a half list's do.
  template <bool Tail, bool Upper = false>
  void build(const VerletList& list, std::span<const std::uint32_t> rows, std::size_t block,
             bool with_entry) {
    const std::uint32_t* off = list.offsets().data();
    const std::uint32_t* wrap = list.wrap_begin().data();
    const std::uint32_t* nb = list.neighbors().data();
    auto first = [&](std::uint32_t r) { return Tail ? wrap[r] : off[r]; };
    auto last = [&](std::uint32_t r) { return Tail ? off[r + 1] : wrap[r]; };
    std::size_t total = 0;
    for (const std::uint32_t r : rows) {
      if constexpr (Upper) {
        for (std::uint32_t e = first(r); e < last(r); ++e)
          total += nb[e] > r;
      } else {
        total += last(r) - first(r);
      }
    }
    i.resize(total), j.resize(total);
    k.resize(with_entry ? total : 0);
    const std::size_t n = rows.size();
    block_start.assign((n + block - 1) / block + 1, 0);
    std::size_t s = 0;
    for (std::size_t q = 0; q < n; ++q) {
      if (q % block == 0)
        block_start[q / block] = static_cast<std::uint32_t>(s);
      const std::uint32_t r = rows[q];
      for (std::uint32_t e = first(r), e1 = last(r); e < e1; ++e) {
        if (Upper && nb[e] < r)
          continue;
        i[s] = r, j[s] = nb[e];
        if (with_entry)
          k[s] = e;
        ++s;
      }
    }
    block_start.back() = static_cast<std::uint32_t>(s);
  }

  // The pairs (a[q], b[q]) with keep(q), in their order, in blocks of `block` pairs, without
  // entries (the orb scheme's candidate pairs: its global steps walk them as the explicit scheme
  // walks its list).
  template <class Keep>
  void build(std::span<const std::uint32_t> a, std::span<const std::uint32_t> b, Keep&& keep,
             std::size_t block) {
    i.clear(), j.clear(), k.clear();
    for (std::size_t q = 0; q < a.size(); ++q)
      if (keep(q))
        i.push_back(a[q]), j.push_back(b[q]);
    const std::size_t n = i.size();
    block_start.resize((n + block - 1) / block + 1);
    for (std::size_t q = 0; q + 1 < block_start.size(); ++q)
      block_start[q] = static_cast<std::uint32_t>(q * block);
    block_start.back() = static_cast<std::uint32_t>(n);
  }
};

} // namespace cfddem::dem
