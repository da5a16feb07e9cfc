// The contacts one block of rows of a half neighbor list produced in a step: the explicit
// scheme's pair pass writes them (dem/verlet_passes.hpp), its scatter adds them to both particles
// of each pair (dem/contact_scatter.hpp).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace cfddem::dem {

// Contacts found by the pair pass in a fixed block of rows, in row order, each pair once (i < j,
// n the unit vector from i to j): a = F_n n, what i loses and j gains, and with friction the
// tangential force b = F_t on i (j gets -b) and c = n x F_t, whose torque is r_i c on i and r_j c
// on j. Arrays only grow (kept between steps); `size` contacts are valid.
struct PairContacts {
  std::size_t size = 0;
  // The least and the greatest particle index the `size` contacts name (i or j): the scatter's
  // range tasks skip the blocks that cannot touch their particles.
  std::uint32_t lo = 0, hi = 0;
  std::vector<std::uint32_t> i, j;
  std::vector<double> ax, ay, az, bx, by, bz, cx, cy, cz;
  // Room for at least `more` further contacts (friction: also b and c).
  void reserve_more(std::size_t more, bool friction) {
    const std::size_t need = size + more;
    if (need <= i.size())
      return;
    const std::size_t cap = std::max<std::size_t>(need, 2 * i.size());
    i.resize(cap), j.resize(cap), ax.resize(cap), ay.resize(cap), az.resize(cap);
    if (friction)
      bx.resize(cap), by.resize(cap), bz.resize(cap), cx.resize(cap), cy.resize(cap),
          cz.resize(cap);
  }
  // Set lo and hi from the `size` contacts.
  void bound_indices() {
    std::uint32_t l = UINT32_MAX, h = 0;
    for (std::size_t s = 0; s < size; ++s) {
      l = std::min({l, i[s], j[s]});
      h = std::max({h, i[s], j[s]});
    }
    lo = l, hi = h;
  }
};

} // namespace cfddem::dem
