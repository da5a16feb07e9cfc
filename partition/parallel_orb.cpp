#include "partition/parallel_orb.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <utility>

#include <mpi.h>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"
#include "core/sparse_exchange_mpi.hpp"
#include "partition/knapsack.hpp"
#include "partition/orb_cut_rules.hpp"
#include "partition/space_filling_curve.hpp"

namespace cfddem::partition {

int shared_orb_levels(int ranks, int levels) {
  const int log2_ranks = std::bit_width(static_cast<unsigned>(std::max(ranks, 1) - 1));
  return std::min(levels, log2_ranks + 3);
}

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

// The ranks that cut one subtree together: the run's communicator (whose MPI wait the calls
// add to) and the group's own.
struct Group {
  const Communicator* run;
  MPI_Comm comm;
  int rank, size;
};

void allreduce(const Group& g, std::vector<double>& v, MPI_Op op) {
  if (g.size == 1) return;
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(double)), true);
  count_messages::orb_search(static_cast<std::int64_t>(v.size() * sizeof(double)));
  MpiWait w(*g.run);
  MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), MPI_DOUBLE, op, g.comm);
}

// The halves of a communicator, cached on it as an MPI attribute (MPI 3.1 §6.7): they depend on
// its size alone, so they are split once (a split is collective and gathers every rank's color)
// and freed with it. Those of MPI_COMM_WORLD live until MPI_Finalize.
int free_halves(MPI_Comm parent, int /*key*/, void* value, void* /*extra*/) {
  auto* halves = static_cast<std::array<MPI_Comm, 2>*>(value);
  if (parent != MPI_COMM_WORLD)
    for (MPI_Comm& c : *halves)
      if (c != MPI_COMM_NULL) MPI_Comm_free(&c);
  delete halves;
  return MPI_SUCCESS;
}

// The half of `parent` that holds this rank (color 0: the lower ranks).
MPI_Comm half_of(MPI_Comm parent, int color, int rank) {
  static const int key = [] {
    int k = MPI_KEYVAL_INVALID;
    MPI_Comm_create_keyval(MPI_COMM_NULL_COPY_FN, free_halves, &k, nullptr);
    return k;
  }();
  void* value = nullptr;
  int found = 0;
  MPI_Comm_get_attr(parent, key, &value, &found);
  auto* halves = static_cast<std::array<MPI_Comm, 2>*>(value);
  if (!found) {
    halves = new std::array<MPI_Comm, 2>{MPI_COMM_NULL, MPI_COMM_NULL};
    MPI_Comm_set_attr(parent, key, halves);
  }
  MPI_Comm& half = (*halves)[static_cast<std::size_t>(color)];
  if (half == MPI_COMM_NULL) MPI_Comm_split(parent, color, rank, &half);
  return half;
}

// This rank's points of the subtree being cut (copies: they move between ranks).
struct Points {
  std::vector<double> x, y, z, w; // w: 1 for each point without weights
  std::vector<double> tag;        // what send_points received with each point
  bool weighted = false;
  [[nodiscard]] std::size_t size() const { return x.size(); }
  [[nodiscard]] std::array<std::span<const double>, 3> coord() const { return {x, y, z}; }
};

// Heap index of the t-th node `d` levels below node n (its depth's nodes in order).
std::size_t descendant(std::size_t n, int d, std::size_t t) {
  return ((n + 1) << d) - 1 + t;
}

// `levels` levels of the subtree with root box `root`, agreed over the group by reductions:
// `cuts` in heap order relative to the root, `boxes` the 2^levels subtrees below them and
// `node_of` each local point's subtree. Every cut is the serial build's (orb_cut_rules.hpp).
void cut_collectively(const Group& g, const Points& p, const Aabb& root, int levels,
                      const std::optional<Grid>& snap, std::vector<OrbCut>& cuts,
                      std::vector<Aabb>& boxes, std::vector<std::uint32_t>& node_of) {
  const std::size_t n = p.size();
  const auto coord = p.coord();
  auto w = [&](std::size_t i) { return p.w[i]; };
  cuts.assign((std::size_t{1} << levels) - 1, OrbCut{});
  boxes.assign(1, root);
  node_of.assign(n, 0);
  for (int level = 0; level < levels; ++level) {
    const std::size_t m = boxes.size();
    // Node weights (counts when unweighted: integers, exact in any summation order).
    std::vector<double> total(m, 0.0), count(m, 0.0);
    for (std::size_t i = 0; i < n; ++i) total[node_of[i]] += w(i), count[node_of[i]] += 1.0;
    allreduce(g, total, MPI_SUM);
    allreduce(g, count, MPI_SUM);

    std::vector<int> axis(m);
    std::vector<detail::FaceRange> faces(m, {0, -1});
    std::vector<bool> unit(m);
    for (std::size_t j = 0; j < m; ++j) {
      axis[j] = detail::cut_axis(boxes[j], snap, faces[j]);
      // All-zero measured cost carries no information: balance the counts (as the serial build).
      unit[j] = !p.weighted || !(total[j] > 0.0);
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
      allreduce(g, bucket, MPI_SUM);
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
      if (snap && axis[j] >= 0) {
        std::int64_t k0 = 0, k1 = 0;
        detail::faces_around(*snap, axis[j], faces[j], cm[j], k0, k1);
        f0[j] = snap->face(axis[j], k0);
        f1[j] = snap->face(axis[j], k1);
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
      if (snap) {
        if (c < f0[j]) w0[j] += weight(i);
        if (c < f1[j]) w1[j] += weight(i);
      }
    }
    allreduce(g, w_less, MPI_SUM);
    allreduce(g, w_eq, MPI_SUM);
    allreduce(g, w0, MPI_SUM);
    allreduce(g, w1, MPI_SUM);
    allreduce(g, prev, MPI_MAX);
    allreduce(g, next, MPI_MIN);

    // Cuts, identical on every rank, and the next level's boxes.
    std::vector<Aabb> children(2 * m);
    const std::size_t first = m - 1; // heap index (relative to the root) of the level's first node
    for (std::size_t j = 0; j < m; ++j) {
      const Aabb& box = boxes[j];
      OrbCut cut;
      if (axis[j] < 0) {
        cut = {box.longest_axis(), box.lo[box.longest_axis()]}; // no face: empty lower sibling
      } else if (count[j] == 0.0) {
        const int a = axis[j];
        const double mid_box = box.lo[a] + 0.5 * box.extent(a);
        cut = {a, snap ? snap->face(a, detail::nearest_face(*snap, a,
                                                                            faces[j], mid_box))
                               : mid_box};
      } else if (!snap) {
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
}

// Sends point i, with tag[i] (0 when empty), to group rank dest[i] (core's sparse exchange, each
// rank's in local order) and returns what arrives, by source rank. The counts go first: to the one partner when
// `partner` >= 0 (a halving's swap), otherwise in an all-to-all over the group.
Points send_points(const Group& g, const Points& p, std::span<const int> dest,
                   std::span<const double> tag, int partner) {
  const auto ranks = static_cast<std::size_t>(g.size);
  constexpr int kStride = 5;
  std::vector<std::int64_t> send_n(ranks, 0), recv_n(ranks, 0);
  for (const int r : dest) ++send_n[static_cast<std::size_t>(r)];
  std::vector<std::size_t> at(ranks, 0);
  for (std::size_t r = 1; r < ranks; ++r) at[r] = at[r - 1] + static_cast<std::size_t>(send_n[r - 1]);
  std::vector<double> send(kStride * p.size()), recv;
  for (std::size_t i = 0; i < p.size(); ++i) {
    double* q = send.data() + kStride * at[static_cast<std::size_t>(dest[i])]++;
    q[0] = p.x[i], q[1] = p.y[i], q[2] = p.z[i], q[3] = p.w[i];
    q[4] = tag.empty() ? 0.0 : tag[i];
  }
  if (partner >= 0) {
    count_messages::point_to_point(sizeof(std::int64_t));
    MpiWait wait(*g.run);
    MPI_Sendrecv(&send_n[static_cast<std::size_t>(partner)], 1, MPI_INT64_T, partner, 7311,
                 &recv_n[static_cast<std::size_t>(partner)], 1, MPI_INT64_T, partner, 7311, g.comm,
                 MPI_STATUS_IGNORE);
    recv_n[static_cast<std::size_t>(g.rank)] = send_n[static_cast<std::size_t>(g.rank)];
  }
  sparse_exchange(*g.run, g.comm, g.rank, g.size, send_n, send, recv_n, recv, kStride,
                  partner >= 0);
  Points out;
  out.weighted = p.weighted;
  const std::size_t m = recv.size() / kStride;
  out.x.resize(m), out.y.resize(m), out.z.resize(m), out.w.resize(m), out.tag.resize(m);
  for (std::size_t j = 0; j < m; ++j) {
    const double* q = recv.data() + kStride * j;
    out.x[j] = q[0], out.y[j] = q[1], out.z[j] = q[2], out.w[j] = q[3], out.tag[j] = q[4];
  }
  return out;
}

// What one rank found: cuts (node, axis, position), the roots of the subtrees it owns, and
// their weight.
struct Found {
  std::vector<double> cuts;
  std::vector<double> roots;
  double load = 0.0;
  // Cuts in heap order relative to node `root` (cut k has children 2k+1 and 2k+2).
  void cuts_below(std::size_t root, std::span<const OrbCut> relative) {
    for (std::size_t k = 0; k < relative.size(); ++k) {
      const int d = std::bit_width(k + 1) - 1; // k's depth below the root
      const std::size_t node = descendant(root, d, k + 1 - (std::size_t{1} << d));
      cuts.insert(cuts.end(), {static_cast<double>(node), static_cast<double>(relative[k].axis),
                               relative[k].position});
    }
  }
};

// The group's stage below node `root` (box `box`, `left` levels to the leaves): the top
// shared_orb_levels(group size) levels by reductions, then the subtrees below them dealt to the
// group's ranks by the Hilbert knapsack over their weights, their points sent there, and each cut
// there alone by the serial rules (orb_subtree_cuts).
void cut_group(const Group& g, const Points& p, std::size_t root, const Aabb& box, int left,
               const std::optional<Grid>& snap, Found& found) {
  const int shared = g.size == 1 ? 0 : shared_orb_levels(g.size, left);
  std::vector<OrbCut> top;
  std::vector<Aabb> boxes;
  std::vector<std::uint32_t> subtree_of;
  cut_collectively(g, p, box, shared, snap, top, boxes, subtree_of);
  if (g.rank == 0) found.cuts_below(root, top);
  const std::size_t subtrees = boxes.size();
  std::vector<double> weight(subtrees, 0.0);
  for (std::size_t i = 0; i < p.size(); ++i) weight[subtree_of[i]] += p.w[i];
  allreduce(g, weight, MPI_SUM);
  std::vector<std::array<double, 3>> centres(subtrees);
  for (std::size_t s = 0; s < subtrees; ++s) centres[s] = boxes[s].centre();
  const KnapsackAssignment k =
      knapsack_along_curve(weight, sfc_order(centres, box, CurveKind::hilbert), g.size);
  // Below the shared levels: this rank's subtrees in heap order, each over its points in arrival
  // order (none to send when the subtrees are leaves).
  const int below = left - shared;
  Points sorted;
  std::vector<std::size_t> first(subtrees + 1, 0);
  if (below > 0) {
    std::vector<int> dest(p.size());
    std::vector<double> tag(p.size());
    for (std::size_t i = 0; i < p.size(); ++i)
      dest[i] = k.owner[subtree_of[i]], tag[i] = static_cast<double>(subtree_of[i]);
    const Points mine = send_points(g, p, dest, tag, -1);
    for (const double s : mine.tag) ++first[static_cast<std::size_t>(s) + 1];
    for (std::size_t s = 0; s < subtrees; ++s) first[s + 1] += first[s];
    const std::size_t m = mine.size();
    sorted.x.resize(m), sorted.y.resize(m), sorted.z.resize(m), sorted.w.resize(m);
    std::vector<std::size_t> at(first.begin(), first.end() - 1);
    for (std::size_t j = 0; j < m; ++j) {
      const std::size_t t = at[static_cast<std::size_t>(mine.tag[j])]++;
      sorted.x[t] = mine.x[j], sorted.y[t] = mine.y[j], sorted.z[t] = mine.z[j];
      sorted.w[t] = mine.w[j];
    }
  }
  for (std::size_t s = 0; s < subtrees; ++s) {
    if (k.owner[s] != g.rank) continue;
    const std::size_t r = descendant(root, shared, s);
    if (below > 0) {
      const std::size_t b = first[s], e = first[s + 1];
      auto part = [&](const std::vector<double>& v) {
        return std::span<const double>(v).subspan(b, e - b);
      };
      found.cuts_below(r, orb_subtree_cuts(part(sorted.x), part(sorted.y), part(sorted.z),
                                           p.weighted ? part(sorted.w) : std::span<const double>(),
                                           boxes[s], OrbOptions{below, snap}));
    }
    found.roots.push_back(static_cast<double>(r));
    found.load += weight[s];
  }
}

// Every rank's findings to every rank, in one all-gather of [load, cuts, roots, (node, axis,
// position)..., root...]: the whole tree, each leaf's rank and each rank's load.
void share(const Communicator& comm, const Found& found, int levels, ParallelOrb& out) {
  std::vector<double> mine{found.load, static_cast<double>(found.cuts.size() / 3),
                           static_cast<double>(found.roots.size())};
  mine.insert(mine.end(), found.cuts.begin(), found.cuts.end());
  mine.insert(mine.end(), found.roots.begin(), found.roots.end());
  const auto ranks = static_cast<std::size_t>(comm.size());
  std::vector<int> counts(ranks), displs(ranks, 0);
  const int size = static_cast<int>(mine.size());
  count_messages::collective(static_cast<std::int64_t>(ranks * sizeof(int)), false);
  {
    MpiWait wait(comm);
    MPI_Allgather(&size, 1, MPI_INT, counts.data(), 1, MPI_INT, mpi_comm(comm));
  }
  for (std::size_t r = 1; r < ranks; ++r) displs[r] = displs[r - 1] + counts[r - 1];
  std::vector<double> all(static_cast<std::size_t>(displs[ranks - 1] + counts[ranks - 1]));
  count_messages::collective(static_cast<std::int64_t>(all.size() * sizeof(double)), false);
  {
    MpiWait wait(comm);
    MPI_Allgatherv(mine.data(), size, MPI_DOUBLE, all.data(), counts.data(), displs.data(),
                   MPI_DOUBLE, mpi_comm(comm));
  }
  out.cuts.assign((std::size_t{1} << levels) - 1, OrbCut{});
  out.leaf_rank.assign(std::size_t{1} << levels, -1);
  out.rank_load.assign(ranks, 0.0);
  for (std::size_t r = 0; r < ranks; ++r) {
    const double* q = all.data() + displs[r];
    out.rank_load[r] = q[0];
    const auto n_cuts = static_cast<std::size_t>(q[1]), n_roots = static_cast<std::size_t>(q[2]);
    const double* c = q + 3;
    for (std::size_t k = 0; k < n_cuts; ++k, c += 3)
      out.cuts[static_cast<std::size_t>(c[0])] = {static_cast<int>(c[1]), c[2]};
    for (std::size_t k = 0; k < n_roots; ++k) {
      const auto root = static_cast<std::size_t>(c[k]);
      const int below = levels - (std::bit_width(root + 1) - 1); // levels under the root
      const std::size_t span = std::size_t{1} << below;
      const std::size_t first = descendant(root, below, 0) - (out.leaf_rank.size() - 1);
      std::fill_n(out.leaf_rank.begin() + static_cast<std::ptrdiff_t>(first), span,
                  static_cast<int>(r));
    }
  }
}

} // namespace

ParallelOrb parallel_orb_cuts(const Communicator& comm, std::span<const double> x,
                              std::span<const double> y, std::span<const double> z,
                              std::span<const double> weights, const Aabb& domain,
                              const OrbOptions& options, int group_ranks) {
  const std::size_t n = x.size();
  if (y.size() != n || z.size() != n || (!weights.empty() && weights.size() != n))
    throw std::invalid_argument("parallel_orb: x, y, z (and weights) must have the same size");
  if (options.levels < 0 || options.levels > 24)
    throw std::invalid_argument("parallel_orb: levels must be in [0, 24]");
  if (group_ranks < 1) throw std::invalid_argument("parallel_orb: group_ranks must be >= 1");
  Points p;
  p.x.assign(x.begin(), x.end()), p.y.assign(y.begin(), y.end()), p.z.assign(z.begin(), z.end());
  p.weighted = !weights.empty();
  if (p.weighted) p.w.assign(weights.begin(), weights.end());
  else p.w.assign(n, 1.0);

  const int levels = options.levels;
  Group g{&comm, mpi_comm(comm), comm.rank(), comm.size()};
  ParallelOrb out;
  out.shared_levels = shared_orb_levels(g.size, levels);
  const bool will_halve = g.size > group_ranks && g.size % 2 == 0;
  if (out.shared_levels == levels && !will_halve) {
    // Few levels and ranks: all of them by reductions; decompose() deals the leaves.
    std::vector<Aabb> boxes;
    std::vector<std::uint32_t> node_of;
    cut_collectively(g, p, domain, levels, options.snap, out.cuts, boxes, node_of);
    return out;
  }
  // Halvings: a group of an even number of ranks above group_ranks agrees on its node's cut, and
  // each rank swaps the other side's points with its partner in the other half.
  Found found;
  std::size_t node = 0;
  int depth = 0;
  Aabb box = domain;
  while (g.size > group_ranks && g.size % 2 == 0 && depth < levels) {
    std::vector<OrbCut> cut;
    std::vector<Aabb> halves;
    std::vector<std::uint32_t> side;
    cut_collectively(g, p, box, 1, options.snap, cut, halves, side);
    if (g.rank == 0) found.cuts_below(node, cut);
    const int half = g.size / 2;
    const int upper = g.rank >= half ? 1 : 0;
    const int partner = upper ? g.rank - half : g.rank + half;
    std::vector<int> dest(p.size());
    for (std::size_t i = 0; i < p.size(); ++i)
      dest[i] = static_cast<int>(side[i]) == upper ? g.rank : partner;
    p = send_points(g, p, dest, {}, partner);
    g = Group{&comm, half_of(g.comm, upper, g.rank), g.rank - upper * half, half};
    node = 2 * node + 1 + static_cast<std::size_t>(upper);
    box = halves[static_cast<std::size_t>(upper)];
    ++depth;
  }
  out.shared_levels = depth + (g.size == 1 ? 0 : shared_orb_levels(g.size, levels - depth));
  cut_group(g, p, node, box, levels - depth, options.snap, found);

  share(comm, found, levels, out);
  return out;
}

} // namespace cfddem::partition
