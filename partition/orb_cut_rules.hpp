// The rules that place one ORB cut, shared by the serial build (orb_tree.cpp) and the parallel one
// (parallel_orb.cpp): given the same statistics of a node's points they give the same cut, bit
// for bit, which is how both builds agree.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>

#include "partition/orb_tree.hpp"

namespace cfddem::partition::detail {

// Faces origin + k*spacing strictly inside (lo, hi): [kmin, kmax], empty when kmin > kmax.
struct FaceRange {
  std::int64_t kmin;
  std::int64_t kmax;
  [[nodiscard]] bool empty() const { return kmin > kmax; }
};

inline FaceRange interior_faces(const Grid& g, int axis, double lo, double hi) {
  const double s = g.spacing[axis];
  // floor/ceil give a first guess; the loops fix rounding so the test is on the face value
  // itself, which is what the cut will be.
  auto kmin = static_cast<std::int64_t>(std::floor((lo - g.origin[axis]) / s));
  while (g.face(axis, kmin) <= lo) {
    ++kmin;
  }
  while (g.face(axis, kmin - 1) > lo) {
    --kmin;
  }
  auto kmax = static_cast<std::int64_t>(std::ceil((hi - g.origin[axis]) / s));
  while (g.face(axis, kmax) >= hi) {
    --kmax;
  }
  while (g.face(axis, kmax + 1) < hi) {
    ++kmax;
  }
  return {kmin, kmax};
}

// Interior face nearest to `target`, ties to the lower one.
inline std::int64_t nearest_face(const Grid& g, int axis, FaceRange r, double target) {
  auto k = static_cast<std::int64_t>(std::floor((target - g.origin[axis]) / g.spacing[axis]));
  k = std::clamp(k, r.kmin, r.kmax);
  const std::int64_t k1 = std::min(k + 1, r.kmax);
  return std::abs(g.face(axis, k1) - target) < std::abs(g.face(axis, k) - target) ? k1 : k;
}

// A position strictly above `below` and at most `hi`, halfway when the doubles allow: used when
// the natural cut (a point's coordinate) would leave a zero-width box.
inline double gap_midpoint(double below, double hi) {
  const double m = below + 0.5 * (hi - below);
  return m > below ? m : hi;
}

// Axis of a node's cut: the longest extent; with snapping, the longest axis that still has an
// interior cell face (its faces in `faces`). -1: no face to cut on (an empty lower sibling).
inline int cut_axis(const Aabb& box, const std::optional<Grid>& snap, FaceRange& faces) {
  if (!snap) return box.longest_axis();
  int best = -1;
  for (int a = 0; a < 3; ++a) {
    const FaceRange r = interior_faces(*snap, a, box.lo[a], box.hi[a]);
    if (!r.empty() && (best < 0 || box.extent(a) > box.extent(best))) {
      best = a;
      faces = r;
    }
  }
  return best;
}

// What the free (unsnapped) cut needs to know about the node's points along the axis: the
// weighted median coordinate cm, the weight strictly below it and at it, the largest coordinate
// below it (prev) and the smallest above it (next), and half the node's weight.
struct MedianStats {
  double cm = 0.0, w_less = 0.0, w_eq = 0.0, half = 0.0;
  double prev = -std::numeric_limits<double>::infinity();
  double next = std::numeric_limits<double>::infinity();
};

// Two cuts bracket the median point: at it (it goes up) or just past it (it and its ties go
// down, the cut at the next larger coordinate). The one closer to W/2 keeps |lower - upper| <=
// the median point's weight. A cut on the hi face would leave a zero-width upper box.
inline double free_cut(const MedianStats& s, double lo, double hi) {
  const double at_median = s.cm < hi ? s.cm : gap_midpoint(std::max(s.prev, lo), hi);
  double position = at_median;
  if (s.cm < hi) {
    const double past_median = std::isfinite(s.next) ? s.next : gap_midpoint(s.cm, hi);
    if (std::abs(s.w_less + s.w_eq - s.half) < std::abs(s.w_less - s.half)) position = past_median;
  }
  return position;
}

// The two interior faces around the median (k0 <= k1).
inline void faces_around(const Grid& g, int axis, FaceRange faces, double cm, std::int64_t& k0,
                         std::int64_t& k1) {
  k0 = static_cast<std::int64_t>(std::floor((cm - g.origin[axis]) / g.spacing[axis]));
  k0 = std::clamp(k0, faces.kmin, faces.kmax);
  k1 = std::min(k0 + 1, faces.kmax);
}

// Of the two faces f0, f1 around cm (weights w0, w1 strictly below them) keep the better
// balanced, ties to the nearer.
inline double snapped_cut(double f0, double f1, double w0, double w1, double half, double cm) {
  const double d0 = std::abs(w0 - half);
  const double d1 = std::abs(w1 - half);
  const bool take1 = d1 < d0 || (d1 == d0 && std::abs(f1 - cm) < std::abs(f0 - cm));
  return take1 ? f1 : f0;
}

} // namespace cfddem::partition::detail
