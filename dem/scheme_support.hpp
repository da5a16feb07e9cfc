// Small pieces the particle schemes share: the sign-bit flag reduction of their check passes and
// the limits of the sub-iterated schemes (orb, islands).
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>

#include <fmt/format.h>

#include "core/error.hpp"
#include "core/scene.hpp"
#include "dem/domain_geometry.hpp"
#include "partition/orb_tree.hpp"

namespace cfddem::dem {

// Sign bit set unless `ok`: OR-ed over a loop it is a flag reduction GCC vectorizes (a bool OR
// is not), the idiom of kick_drift_range (kick_drift_range.hpp).
inline std::uint64_t sign_unless(bool ok) {
  return std::bit_cast<std::uint64_t>(ok ? 1.0 : -1.0);
}

// The grid the orb schemes' ORB cuts snap to: with a gas, its cell faces, so that every leaf is
// a whole number of cells (the box is the unit of both the particles and the fluid); none
// without. The serial and the distributed orb scheme must agree on it to share their leaves.
inline std::optional<partition::Grid> orb_snap_grid(const Scene& scene) {
  if (!scene.fluid.enabled)
    return std::nullopt;
  partition::Grid grid;
  for (int a = 0; a < 3; ++a)
    grid.origin[a] = scene.domain.lo[a],
    grid.spacing[a] = scene.fluid.cell_size[a] > 0.0
                          ? scene.fluid.cell_size[a]
                          : scene.domain.length(a) / static_cast<double>(scene.fluid.cells[a]);
  return grid;
}

// The fine steps of one sub-iteration of length dt_sp for a contact step dt: K = ceil(dt_sp / dt)
// steps of dt (a relative slack of 1e-9 absorbs rounding when dt divides dt_sp), the last one
// shortened to dt_sp - (K-1) dt so that the particle lands on the sub-iteration's end; or one
// step of dt_sp when dt >= dt_sp. Every sub-iterated scheme (orb, islands, on any rank count)
// takes its fine steps from here.
struct FineSteps {
  std::int64_t K = 1;
  double h = 0.0, h_last = 0.0;
};
inline FineSteps fine_steps(double dt_sp, double dt) {
  FineSteps f;
  const bool can_refine = dt < dt_sp;
  f.K = can_refine
            ? std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(dt_sp / dt - 1e-9)))
            : 1;
  f.h = can_refine ? dt : dt_sp;
  f.h_last = dt_sp - static_cast<double>(f.K - 1) * f.h;
  return f;
}

// The closed interval a coordinate must stay in on each axis: the walls, or an infinite interval
// on a periodic axis (so one comparison per axis checks walls and catches NaN, branch-free).
struct WallBounds {
  double lo[3], hi[3];
  explicit WallBounds(const DomainGeometry& g) {
    const double inf = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a)
      lo[a] = g.periodic[a] ? -inf : g.lo[a], hi[a] = g.periodic[a] ? inf : g.hi[a];
  }
};

// A particle's halo box `q` lies strictly inside the leaf holding the particle at (x, y, z): it
// reaches no other leaf and no periodic image, so the particle needs no ghost copy (most
// particles of a large box). The R-rank ghost searches take this fast path first.
inline bool halo_inside_own_leaf(const partition::OrbTree& tree, double x, double y, double z,
                                 const partition::Aabb& q) {
  const int own = tree.locate(x, y, z);
  if (own < 0)
    return false;
  const partition::Aabb& b = tree.leaves()[static_cast<std::size_t>(own)].box;
  for (int a = 0; a < 3; ++a)
    if (!(q.lo[a] > b.lo[a] && q.hi[a] < b.hi[a]))
      return false;
  return true;
}

// The largest skin a list may grow to while its cutoff 2 r_max + skin stays below half of every
// periodic length (minimum image); infinite without a periodic axis.
inline double periodic_skin_cap(const DomainGeometry& g, double r_max) {
  double cap = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a)
    if (g.periodic[a])
      cap = std::min(cap, 0.499 * g.length[a] - 2.0 * r_max);
  return cap;
}

// The two stops at that cap (orb, islands on one and R ranks), at time t, ending in `advice`:
// a fresh list would need the skin for a travel beyond it, or a particle outran half of the
// largest skin it allows.
inline std::string travel_beyond_skin_cap(double t, double travel, double cap,
                                          std::string_view advice) {
  return fmt::format("t = {:.9g} s: particles may move {:.4g} m in one sub-iteration, more than "
                     "the periodic box allows for a neighbor skin ({:.4g} m): {}",
                     t, travel, cap, advice);
}
inline std::string outran_skin_cap(double t, double skin, std::string_view advice) {
  return fmt::format("t = {:.9g} s: a particle moves more than half the neighbor skin in one "
                     "sub-iteration even with the largest skin the periodic box allows ({:.4g} "
                     "m): {}",
                     t, skin, advice);
}

} // namespace cfddem::dem
