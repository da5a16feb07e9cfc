#include "partition/parallel_orb.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <stdexcept>

#include <mpi.h>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"
#include "core/sparse_exchange.hpp"
#include "partition/knapsack.hpp"
#include "partition/orb_cut_rules.hpp"
#include "partition/space_filling_curve.hpp"

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

void allreduce(const Communicator& comm, std::vector<double>& v, MPI_Op op) {
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(double)), true);
  MpiWait w(comm);
  MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), MPI_DOUBLE, op,
                mpi_comm(comm));
}

} // namespace

int shared_orb_levels(int ranks, int levels) {
  const int log2_ranks = std::bit_width(static_cast<unsigned>(std::max(ranks, 1) - 1));
  return std::min(levels, log2_ranks + 3);
}

namespace {

// The subtrees below the shared levels (boxes, and the subtree of each local point): dealt to
// ranks by the Hilbert knapsack over their weights, their points sent there, cut there by the
// serial rules, and the cuts shared with every rank (one all-gather, 16 bytes per cut).
void cut_subtrees(const Communicator& comm, const std::array<std::span<const double>, 3>& coord,
                  std::span<const double> weights, const std::vector<Aabb>& boxes,
                  const std::vector<std::uint32_t>& subtree_of, const Aabb& domain,
                  const OrbOptions& options, ParallelOrb& out) {
  const std::size_t n = subtree_of.size(), subtrees = boxes.size();
  const int ranks = comm.size(), me = comm.rank();
  const int below = options.levels - out.shared_levels;
  // Weights per subtree (counts without weights: integers, exact in any order).
  std::vector<double> weight(subtrees, 0.0);
  for (std::size_t i = 0; i < n; ++i)
    weight[subtree_of[i]] += weights.empty() ? 1.0 : weights[i];
  allreduce(comm, weight, MPI_SUM);
  std::vector<std::array<double, 3>> centres(subtrees);
  for (std::size_t s = 0; s < subtrees; ++s) centres[s] = boxes[s].centre();
  const KnapsackAssignment k =
      knapsack_along_curve(weight, sfc_order(centres, domain, CurveKind::hilbert), ranks);
  out.subtree_rank = k.owner;
  out.subtree_weight = weight;

  // Every point (x, y, z, weight, subtree) to the rank of its subtree, in local order.
  constexpr int kStride = 5;
  std::vector<std::int64_t> send_counts(static_cast<std::size_t>(ranks), 0), recv_counts;
  for (std::size_t i = 0; i < n; ++i) ++send_counts[static_cast<std::size_t>(k.owner[subtree_of[i]])];
  std::vector<std::size_t> cursor(static_cast<std::size_t>(ranks) + 1, 0);
  for (int r = 0; r < ranks; ++r) cursor[r + 1] = cursor[r] + static_cast<std::size_t>(send_counts[r]);
  std::vector<double> send(n * kStride), recv;
  for (std::size_t i = 0; i < n; ++i) {
    double* q = send.data() + kStride * cursor[static_cast<std::size_t>(k.owner[subtree_of[i]])]++;
    q[0] = coord[0][i], q[1] = coord[1][i], q[2] = coord[2][i];
    q[3] = weights.empty() ? 1.0 : weights[i], q[4] = static_cast<double>(subtree_of[i]);
  }
  sparse_exchange(comm, send_counts, send, recv_counts, recv, kStride, false);

  // This rank's subtrees, in heap order: their points in arrival order, then their cuts.
  const std::size_t arrived = recv.size() / kStride;
  std::vector<std::size_t> first(subtrees + 1, 0);
  for (std::size_t j = 0; j < arrived; ++j)
    ++first[static_cast<std::size_t>(recv[kStride * j + 4]) + 1];
  for (std::size_t s = 0; s < subtrees; ++s) first[s + 1] += first[s];
  std::vector<double> px(arrived), py(arrived), pz(arrived), pw(weights.empty() ? 0 : arrived);
  {
    std::vector<std::size_t> at(first.begin(), first.end() - 1);
    for (std::size_t j = 0; j < arrived; ++j) {
      const double* q = recv.data() + kStride * j;
      const std::size_t t = at[static_cast<std::size_t>(q[4])]++;
      px[t] = q[0], py[t] = q[1], pz[t] = q[2];
      if (!pw.empty()) pw[t] = q[3];
    }
  }
  const std::size_t per_subtree = (std::size_t{1} << below) - 1; // cuts in one subtree
  std::vector<double> mine;
  for (std::size_t s = 0; s < subtrees; ++s) {
    if (k.owner[s] != me) continue;
    const std::size_t b = first[s], e = first[s + 1];
    auto part = [&](const std::vector<double>& v) {
      return v.empty() ? std::span<const double>() : std::span<const double>(v).subspan(b, e - b);
    };
    for (const OrbCut& c : orb_subtree_cuts(part(px), part(py), part(pz), part(pw), boxes[s],
                                            OrbOptions{below, options.snap}))
      mine.push_back(static_cast<double>(c.axis)), mine.push_back(c.position);
  }

  // Every rank's subtrees' cuts, in rank order (each rank's subtrees in heap order).
  std::vector<int> counts(static_cast<std::size_t>(ranks), 0), displs(static_cast<std::size_t>(ranks), 0);
  for (std::size_t s = 0; s < subtrees; ++s)
    counts[static_cast<std::size_t>(k.owner[s])] += static_cast<int>(2 * per_subtree);
  for (int r = 1; r < ranks; ++r) displs[r] = displs[r - 1] + counts[r - 1];
  std::vector<double> all(static_cast<std::size_t>(displs[ranks - 1] + counts[ranks - 1]));
  count_messages::collective(static_cast<std::int64_t>(all.size() * sizeof(double)), false);
  {
    MpiWait w(comm);
    MPI_Allgatherv(mine.data(), static_cast<int>(mine.size()), MPI_DOUBLE, all.data(),
                   counts.data(), displs.data(), MPI_DOUBLE, mpi_comm(comm));
  }
  // Cut j of subtree s's own heap, at depth d (j = 2^d - 1 + t), is node 2^(shared + d) - 1 +
  // s 2^d + t of the whole tree.
  std::vector<std::size_t> next(displs.begin(), displs.end());
  for (std::size_t s = 0; s < subtrees; ++s) {
    const double* c = all.data() + next[static_cast<std::size_t>(k.owner[s])];
    next[static_cast<std::size_t>(k.owner[s])] += 2 * per_subtree;
    for (int d = 0; d < below; ++d) {
      const std::size_t width = std::size_t{1} << d;
      for (std::size_t t = 0; t < width; ++t) {
        const std::size_t j = width - 1 + t;
        const std::size_t node = (std::size_t{1} << (out.shared_levels + d)) - 1 + s * width + t;
        out.cuts[node] = {static_cast<int>(c[2 * j]), c[2 * j + 1]};
      }
    }
  }
}

} // namespace

ParallelOrb parallel_orb_cuts(const Communicator& comm, std::span<const double> x,
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
  ParallelOrb out;
  out.cuts.resize(n_leaves - 1);
  out.shared_levels = shared_orb_levels(comm.size(), options.levels);
  std::vector<OrbCut>& cuts = out.cuts;
  std::vector<Aabb> boxes{domain};
  std::vector<std::uint32_t> node_of(n, 0); // node of the current level holding each point

  for (int level = 0; level < out.shared_levels; ++level) {
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
  if (out.shared_levels < options.levels)
    cut_subtrees(comm, coord, weights, boxes, node_of, domain, options, out);
  return out;
}

} // namespace cfddem::partition
