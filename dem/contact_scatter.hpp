// The pair passes' contacts (PairContacts blocks) into per-particle sums: clearing the forces the
// last step's contacts left, and adding this step's contacts to both particles of each pair. Both
// run over ranges of particle indices as TBB tasks: a task walks the blocks in their order and
// writes only its own particles, so each particle sums its contacts in exactly the order of one
// serial walk, whatever the ranges and the thread count (bitwise the same results).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>

#include "core/particle_store.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/task_blocks.hpp"

namespace cfddem::dem {

namespace detail {
// Whether block c can name a particle of [a, b): its index bounds (set by the pair pass) meet it.
inline bool block_meets(const PairContacts& c, std::size_t a, std::size_t b) {
  return c.size > 0 && c.hi >= a && c.lo < b;
}
inline bool block_within(const PairContacts& c, std::size_t a, std::size_t b) {
  return c.lo >= a && c.hi < b;
}

// The contacts of `blocks`, in order, seen from the particles of [a, b): on_i(c, s, i) where
// contact s of block c has its i in the range, then on_j(c, s, j) where its j is.
template <class OnI, class OnJ>
void walk_range(std::span<const PairContacts> blocks, std::size_t a, std::size_t b, OnI&& on_i,
                OnJ&& on_j) {
  for (const PairContacts& c : blocks) {
    if (!block_meets(c, a, b))
      continue;
    if (block_within(c, a, b)) {
      for (std::size_t s = 0; s < c.size; ++s)
        on_i(c, s, c.i[s]), on_j(c, s, c.j[s]);
      continue;
    }
    for (std::size_t s = 0; s < c.size; ++s) {
      const std::uint32_t i = c.i[s], j = c.j[s];
      if (i >= a && i < b)
        on_i(c, s, i);
      if (j >= a && j < b)
        on_j(c, s, j);
    }
  }
}
} // namespace detail

// Zero the contact force (and torque, with friction) of particle i.
template <bool Friction> inline void clear_force(ParticleStore& p, std::uint32_t i) {
  p.fx[i] = p.fy[i] = p.fz[i] = 0.0;
  if constexpr (Friction)
    p.tx[i] = p.ty[i] = p.tz[i] = 0.0;
}

// Zero the contact forces (and torques, with friction) of particles `idx`.
template <bool Friction> void clear_forces(ParticleStore& p, std::span<const std::uint32_t> idx) {
  for (const std::uint32_t i : idx)
    clear_force<Friction>(p, i);
}

// Zero the forces (and torques) of both particles of every contact of `head` and `tail`, and of
// the particles `also` (increasing: those that may hold a wall force), over particles [0, n)
// (every index the blocks name is below n). After a scatter of these contacts only those particles
// hold a non-zero contact force: in a dense gas a few percent of the listed particles touch in a
// step, so clearing these instead of every listed particle saves most of the stores (which miss).
template <bool Friction>
void clear_contact_forces(ParticleStore& p, std::size_t n, std::span<const PairContacts> head,
                          std::span<const PairContacts> tail, std::span<const std::uint32_t> also,
                          std::size_t min_range = kParticleRange) {
  for_particle_ranges(
      n,
      [&](std::size_t a, std::size_t b) {
        auto clear = [&](const PairContacts&, std::size_t, std::uint32_t i) {
          clear_force<Friction>(p, i);
        };
        detail::walk_range(head, a, b, clear, clear);
        detail::walk_range(tail, a, b, clear, clear);
        clear_forces<Friction>(p, listed_in(also, a, b));
      },
      min_range);
}

// Contact forces (and torques, with friction) from the contacts of the pair passes, added to f
// (and t) of particles [0, n), which the caller has cleared where it was not zero
// (clear_contact_forces): each contact is added to both its particles, the head blocks in order
// and then the tail blocks. A particle thus sums its pairs in the order of a full list's row
// (in-box partners by index, then partners across a face by index; on R ranks owned partners,
// then ghosts), bit for bit what a full list gives, for any thread count.
template <bool Friction>
void scatter_contacts(ParticleStore& p, std::size_t n, std::span<const PairContacts> head,
                      std::span<const PairContacts> tail, std::size_t min_range = kParticleRange) {
  double* __restrict fx = p.fx.data();
  double* __restrict fy = p.fy.data();
  double* __restrict fz = p.fz.data();
  [[maybe_unused]] double* __restrict tx = p.tx.data();
  [[maybe_unused]] double* __restrict ty = p.ty.data();
  [[maybe_unused]] double* __restrict tz = p.tz.data();
  [[maybe_unused]] const double* __restrict rad = p.radius.data();
  auto to_i = [&](const PairContacts& c, std::size_t s, std::uint32_t i) {
    fx[i] -= c.ax[s], fy[i] -= c.ay[s], fz[i] -= c.az[s];
    if constexpr (Friction) {
      fx[i] += c.bx[s], fy[i] += c.by[s], fz[i] += c.bz[s];
      tx[i] += rad[i] * c.cx[s], ty[i] += rad[i] * c.cy[s], tz[i] += rad[i] * c.cz[s];
    }
  };
  auto to_j = [&](const PairContacts& c, std::size_t s, std::uint32_t j) {
    fx[j] += c.ax[s], fy[j] += c.ay[s], fz[j] += c.az[s];
    if constexpr (Friction) {
      fx[j] -= c.bx[s], fy[j] -= c.by[s], fz[j] -= c.bz[s];
      tx[j] += rad[j] * c.cx[s], ty[j] += rad[j] * c.cy[s], tz[j] += rad[j] * c.cz[s];
    }
  };
  for_particle_ranges(
      n,
      [&](std::size_t a, std::size_t b) {
        detail::walk_range(head, a, b, to_i, to_j);
        detail::walk_range(tail, a, b, to_i, to_j);
      },
      min_range);
}

} // namespace cfddem::dem
