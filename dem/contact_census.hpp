// The contacts of a particle state, counted the same way whatever scheme produced the state: the
// pairs and wall contacts with overlap > 0, their overlaps relative to the diameter, the
// coordination-number histogram and a collision-frequency estimate. Taken at the diagnostics
// outputs only, from the synchronised positions, with a search of its own over the shared cell
// list (dem/cell_list.hpp): no scheme's lists, leaves or islands are read, so explicit, orb and
// islands are measured alike.
//
// Collision frequency (docs/theory.md §3.1, docs/schemes.md "The contact census"): a contact
// between i and j of the linear spring-dashpot lasts t_c,ij = pi / omega_d(m_eff,ij)
// (contact_damping.hpp). In a steady stream of binary collisions the number of pair contacts
// open at an instant is the collision rate times t_c (Little's law), so the rate is
// sum_contacts 1 / t_c,ij and the frequency per particle (two particles per collision)
//     f = (2 / N) sum_contacts 1 / t_c,ij      (= 2 N_c / (N t_c) for equal masses).
// It is an estimate valid for binary collisions: an enduring contact (a packed bed, a particle
// resting on a wall) counts as a collision every t_c. With e = 0 (critical damping, t_c
// infinite) the estimate is 0. Walls likewise: f_wall = (1 / N) sum_wall_contacts 1 / t_c,w,
// with m_eff = m_i and the wall's spring and restitution.
//
// Deterministic: the overlaps and rates are summed in fixed point (2^-32 of the diameter, and of
// the lightest pair's rate 1 / t_c), so the values depend on the state alone, not on the order
// the particles come in (rank count, scheme, thread count); the means carry that quantisation
// (below 1e-9 of the diameter).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "dem/cell_list.hpp"
#include "dem/domain_geometry.hpp"

namespace cfddem::dem {

// Coordination numbers 0 .. kCoordinationBins - 2 have a bin each; the last bin counts the
// particles with kCoordinationBins - 1 or more pair contacts.
inline constexpr int kCoordinationBins = 13;

struct CensusParticles {
  std::span<const double> x, y, z, radius, mass;
};

// Normal springs and restitution coefficients of the pair and wall contacts (scene keys
// dem.spring_constant, dem.restitution, dem.wall_spring_constant, dem.wall_restitution).
struct CensusLaws {
  double k_pair = 0.0, e_pair = 0.0, k_wall = 0.0, e_wall = 0.0;
};

struct ContactCensus {
  std::int64_t particles = 0;
  std::int64_t pair_contacts = 0; // pairs with r_i + r_j - |x_i - x_j| > 0 (minimum image)
  std::int64_t wall_contacts = 0; // (particle, wall) with r_i - distance to the wall > 0
  // Overlap relative to the diameter: delta / (r_i + r_j) for a pair, delta / (2 r_i) at a wall.
  // Means over the contacts (0 when there are none).
  double pair_overlap_mean = 0.0, pair_overlap_max = 0.0;
  double wall_overlap_mean = 0.0, wall_overlap_max = 0.0;
  double collision_frequency = 0.0;      // f per particle [1/s], pair contacts (above)
  double wall_collision_frequency = 0.0; // f_wall per particle [1/s]
  std::array<std::int64_t, kCoordinationBins> coordination{}; // particles per pair-contact count
};

// Scratch arrays of a census, kept between calls so that a census taken at every output does not
// allocate (and page-fault) afresh each time. Its contents between calls mean nothing.
struct CensusWorkspace {
  CellList cells;
  std::array<std::vector<double>, 5> slot; // x, y, z (wrapped), radius, mass in slot order
  std::vector<int> z;                      // pair-contact counts per slot
};

ContactCensus take_census(const CensusParticles& p, const DomainGeometry& g, const CensusLaws& l,
                          CensusWorkspace& work);
ContactCensus take_census(const CensusParticles& p, const DomainGeometry& g, const CensusLaws& l);

} // namespace cfddem::dem
