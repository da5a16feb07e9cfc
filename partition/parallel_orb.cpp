#include "partition/parallel_orb.hpp"

#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <stdexcept>

#include "core/message_counts.hpp"
#include "partition/orb_cut_rules.hpp"

namespace cfddem::partition {

namespace {

// A monotone map of doubles to unsigned integers: a < b  <=>  key(a) < key(b) (for non-NaN,
// with -0 ordered just below +0; coordinates inside a domain are never both).
std::uint64_t key_of(double v) {
  const auto u = std::bit_cast<std::uint64_t>(v);
  return (u >> 63) ? ~u : (u | (std::uint64_t{1} << 63));
}
double value_of(std::uint64_t k) {
  const std::uint64_t u = (k >> 63) ? (k & ~(std::uint64_t{1} << 63)) : ~k;
  return std::bit_cast<double>(u);
}

void allreduce(MPI_Comm comm, std::vector<double>& v, MPI_Op op) {
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(double)), true);
  MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), MPI_DOUBLE, op, comm);
}

} // namespace

std::vector<OrbCut> parallel_orb_cuts(MPI_Comm comm, std::span<const double> x,
                                      std::span<const double> y, std::span<const double> z,
                                      std::span<const double> weights, const Aabb& domain,
                                      const OrbOptions& options) {
  const std::size_t n = x.size();
  if (y.size() != n || z.size() != n || (!weights.empty() && weights.size() != n))
    throw std::invalid_argument("parallel_orb: x, y, z (and weights) must have the same size");
  if (options.levels < 0 || options.levels > 24)
    throw std::invalid_argument("parallel_orb: levels must be in [0, 24]");
  const std::array<std::span<const double>, 3> coord{x, y, z};
  auto w = [&](std::size_t i) { return weights.empty() ? 1.0 : weights[i]; };

  const std::size_t n_leaves = std::size_t{1} << options.levels;
  std::vector<OrbCut> cuts(n_leaves - 1);
  std::vector<Aabb> boxes{domain};
  std::vector<std::uint32_t> node_of(n, 0); // node of the current level holding each point

  for (int level = 0; level < options.levels; ++level) {
    const std::size_t m = boxes.size();
    // Node weights (counts when unweighted: integers, exact in any summation order).
    std::vector<double> total(m, 0.0), count(m, 0.0);
    for (std::size_t i = 0; i < n; ++i) total[node_of[i]] += w(i), count[node_of[i]] += 1.0;
    allreduce(comm, total, MPI_SUM);
    allreduce(comm, count, MPI_SUM);

    std::vector<int> axis(m);
    std::vector<detail::FaceRange> faces(m, {0, -1});
    std::vector<bool> unit(m);
    for (std::size_t j = 0; j < m; ++j) {
      axis[j] = detail::cut_axis(boxes[j], options.snap, faces[j]);
      // All-zero measured cost carries no information: balance the counts (as the serial build).
      unit[j] = weights.empty() || !(total[j] > 0.0);
      if (unit[j]) total[j] = count[j];
    }
    auto weight = [&](std::size_t i) { return unit[node_of[i]] ? 1.0 : w(i); };

    // Weighted median coordinate of every node at once: the smallest key K with
    // W(coordinate <= K) >= W/2, searched on the 64-bit key with kBuckets - 1 pivots per round
    // (one allreduce of the weight between pivots narrows the range by kBuckets: 8 rounds for 64
    // bits where bisection took 64 allreduces). Every rank takes the same branches: the sums are
    // reduced before they are compared. The answer is unique, so it is bisection's; with integer
    // weights (counts, measured steps) every sum is exact in any order.
    constexpr std::uint64_t kBuckets = 256;
    std::vector<std::uint64_t> lo(m, 0), hi(m, std::numeric_limits<std::uint64_t>::max()),
        step(m, 1);
    std::vector<double> bucket(m * (kBuckets + 1));
    for (std::size_t j = 0; j < m; ++j)
      if (axis[j] < 0 || count[j] == 0.0) hi[j] = 0; // no median needed: done
    // Pivot k of node j: the largest key of bucket k (the last bucket ends at hi).
    auto pivot = [&](std::size_t j, std::uint64_t k) {
      return k + 1 > (hi[j] - lo[j]) / step[j] ? hi[j] : lo[j] + (k + 1) * step[j] - 1;
    };
    while (true) {
      bool open = false;
      for (std::size_t j = 0; j < m; ++j) {
        step[j] = (hi[j] - lo[j]) / kBuckets + 1; // kBuckets steps cover [lo, hi]
        open = open || lo[j] != hi[j];
      }
      if (!open) break;
      // bucket[j][0]: weight below lo; bucket[j][1 + k]: weight in bucket k.
      std::fill(bucket.begin(), bucket.end(), 0.0);
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint32_t j = node_of[i];
        if (axis[j] < 0 || lo[j] == hi[j]) continue;
        const std::uint64_t k = key_of(coord[axis[j]][i]);
        if (k > hi[j]) continue;
        bucket[j * (kBuckets + 1) + (k < lo[j] ? 0 : 1 + (k - lo[j]) / step[j])] += weight(i);
      }
      allreduce(comm, bucket, MPI_SUM);
      for (std::size_t j = 0; j < m; ++j) {
        if (lo[j] == hi[j]) continue;
        const double* b = bucket.data() + j * (kBuckets + 1);
        double below = b[0];
        for (std::uint64_t k = 0; k < kBuckets; ++k) {
          below += b[1 + k];
          if (below >= 0.5 * total[j] || pivot(j, k) == hi[j]) {
            const std::uint64_t top = pivot(j, k);
            lo[j] = k == 0 ? lo[j] : pivot(j, k - 1) + 1;
            hi[j] = top;
            break;
          }
        }
      }
    }

    // The statistics the cut rules need, reduced across ranks.
    std::vector<double> w_less(m, 0.0), w_eq(m, 0.0), w0(m, 0.0), w1(m, 0.0);
    std::vector<double> prev(m, -std::numeric_limits<double>::infinity());
    std::vector<double> next(m, std::numeric_limits<double>::infinity());
    std::vector<double> cm(m), f0(m), f1(m);
    for (std::size_t j = 0; j < m; ++j) {
      cm[j] = value_of(hi[j]);
      if (options.snap && axis[j] >= 0) {
        std::int64_t k0 = 0, k1 = 0;
        detail::faces_around(*options.snap, axis[j], faces[j], cm[j], k0, k1);
        f0[j] = options.snap->face(axis[j], k0);
        f1[j] = options.snap->face(axis[j], k1);
      }
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t j = node_of[i];
      if (axis[j] < 0) continue;
      const double c = coord[axis[j]][i];
      if (c < cm[j]) {
        w_less[j] += weight(i);
        prev[j] = std::max(prev[j], c);
      } else if (c == cm[j]) {
        w_eq[j] += weight(i);
      } else {
        next[j] = std::min(next[j], c);
      }
      if (options.snap) {
        if (c < f0[j]) w0[j] += weight(i);
        if (c < f1[j]) w1[j] += weight(i);
      }
    }
    allreduce(comm, w_less, MPI_SUM);
    allreduce(comm, w_eq, MPI_SUM);
    allreduce(comm, w0, MPI_SUM);
    allreduce(comm, w1, MPI_SUM);
    allreduce(comm, prev, MPI_MAX);
    allreduce(comm, next, MPI_MIN);

    // Cuts, identical on every rank, and the next level's boxes.
    std::vector<Aabb> children(2 * m);
    const std::size_t first = m - 1; // heap index of the level's first node
    for (std::size_t j = 0; j < m; ++j) {
      const Aabb& box = boxes[j];
      OrbCut cut;
      if (axis[j] < 0) {
        cut = {box.longest_axis(), box.lo[box.longest_axis()]}; // no face: empty lower sibling
      } else if (count[j] == 0.0) {
        const int a = axis[j];
        const double mid_box = box.lo[a] + 0.5 * box.extent(a);
        cut = {a, options.snap ? options.snap->face(a, detail::nearest_face(*options.snap, a,
                                                                            faces[j], mid_box))
                               : mid_box};
      } else if (!options.snap) {
        detail::MedianStats st;
        st.cm = cm[j], st.w_less = w_less[j], st.w_eq = w_eq[j], st.half = 0.5 * total[j];
        st.prev = prev[j], st.next = next[j];
        cut = {axis[j], detail::free_cut(st, box.lo[axis[j]], box.hi[axis[j]])};
      } else {
        cut = {axis[j], detail::snapped_cut(f0[j], f1[j], w0[j], w1[j], 0.5 * total[j], cm[j])};
      }
      cuts[first + j] = cut;
      children[2 * j] = box;
      children[2 * j].hi[cut.axis] = cut.position;
      children[2 * j + 1] = box;
      children[2 * j + 1].lo[cut.axis] = cut.position;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const OrbCut& cut = cuts[first + node_of[i]];
      node_of[i] = 2 * node_of[i] + (coord[cut.axis][i] < cut.position ? 0 : 1);
    }
    boxes.swap(children);
  }
  return cuts;
}

OrbTree parallel_orb(MPI_Comm comm, std::span<const double> x, std::span<const double> y,
                     std::span<const double> z, std::span<const double> weights,
                     const Aabb& domain, const OrbOptions& options) {
  return OrbTree::from_cuts(x, y, z, domain, options.levels,
                            parallel_orb_cuts(comm, x, y, z, weights, domain, options));
}

} // namespace cfddem::partition
