// The gas's load-balancing regrid: the weighted ORB of cell boxes (core/cell_box) and the move
// of a distributed grid's owned points from one cutting to another (fluid/grid_move).
#include <algorithm>
#include <array>
#include <vector>

#include <gtest/gtest.h>

#include "core/cell_box.hpp"
#include "core/communicator.hpp"
#include "fluid/grid_halo.hpp"
#include "fluid/grid_move.hpp"
#include "test_grids.hpp"

namespace cfddem::fluid {
namespace {

// Per-cell weight: 1, and `heavy` in the first `rows` rows along y (a dense bottom).
struct Load {
  double heavy = 21.0;
  int rows = 8;
  double cell(int j) const { return j < rows ? heavy : 1.0; }
  double box(const CellBox& b) const {
    double w = 0.0;
    for (int j = b.lo[1]; j < b.hi[1]; ++j) w += cell(j);
    return w * b.cells(0) * b.cells(2);
  }
  SlabWeights slabs() const {
    return [this](const CellBox& b, int axis) {
      std::vector<double> w(static_cast<std::size_t>(b.cells(axis)));
      for (int s = 0; s < b.cells(axis); ++s) {
        CellBox slab = b;
        slab.lo[axis] = b.lo[axis] + s, slab.hi[axis] = slab.lo[axis] + 1;
        w[static_cast<std::size_t>(s)] = box(slab);
      }
      return w;
    };
  }
};

TEST(WeightedCellBoxes, EqualWeightsCutAsTheCellCount) {
  // One weight per cell: the weighted rule ties exactly where the count rule rounds half up.
  const SlabWeights ones = [](const CellBox& b, int axis) {
    return std::vector<double>(static_cast<std::size_t>(b.cells(axis)),
                               static_cast<double>(b.count() / b.cells(axis)));
  };
  for (const std::array<int, 3> cells :
       {std::array<int, 3>{20, 20, 20}, {9, 11, 7}, {32, 50, 32}, {12, 8, 6}, {7, 30, 3}}) {
    for (int parts = 1; parts <= 6; ++parts) {
      std::vector<CellBox> counted;
      try {
        counted = orb_cell_boxes(cells, parts, kMinBoxWidth);
      } catch (const std::invalid_argument&) {
        continue;
      }
      EXPECT_EQ(orb_cell_boxes(cells, parts, kMinBoxWidth, ones), counted)
          << cells[0] << "x" << cells[1] << "x" << cells[2] << " into " << parts;
    }
  }
}

TEST(WeightedCellBoxes, BalanceADenseBottom) {
  // 8 x 32 x 8 cells, the bottom quarter 21 times as costly. Each cut misses its target by at
  // most half a slab, so the heaviest box exceeds the mean by at most half the heaviest slab per
  // level of the recursion; the count rule's boxes are far off (the bottom box carries 11/12).
  const std::array<int, 3> cells = {8, 32, 8};
  const Load load;
  const CellBox all{{0, 0, 0}, cells};
  double slab_max = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    for (const double w : load.slabs()(all, axis)) slab_max = std::max(slab_max, w);
  }
  for (const int parts : {2, 3, 4}) {
    const std::vector<CellBox> weighted = orb_cell_boxes(cells, parts, kMinBoxWidth, load.slabs());
    const std::vector<CellBox> counted = orb_cell_boxes(cells, parts, kMinBoxWidth);
    const auto imbalance = [&](const std::vector<CellBox>& boxes) {
      double worst = 0.0, total = 0.0;
      std::int64_t n = 0;
      for (const CellBox& b : boxes) {
        worst = std::max(worst, load.box(b)), total += load.box(b), n += b.count();
      }
      EXPECT_EQ(n, all.count()) << "the boxes must tile the grid";
      return worst / (total / parts);
    };
    const int levels = parts <= 2 ? 1 : 2;
    const double mean = load.box(all) / parts;
    EXPECT_LE(imbalance(weighted), 1.0 + levels * 0.5 * slab_max / mean) << parts << " parts";
    EXPECT_GT(imbalance(counted), 1.5) << parts << " parts";
  }
}

TEST(GridMove, EveryOwnedPointReachesItsNewOwnerBitwise) {
  // Periodic x, walls along y and z (owned high faces), from the count cutting to a weighted
  // one: every owned point of every centring carries its global index code to its new owner,
  // and the ghosts of the target are left alone.
  const Communicator comm = Communicator::world();
  MacGridSpec spec = test::box_spec({12, 16, 6}, {1.2e-3, 1.6e-3, 6e-4}, BoundaryKind::wall);
  test::set_axis(spec, 0, BoundaryKind::periodic);
  const std::vector<CellBox> old_boxes = orb_cell_boxes(spec.cells, comm.size(), kMinBoxWidth);
  Load load;
  load.rows = 5;
  const std::vector<CellBox> new_boxes =
      orb_cell_boxes(spec.cells, comm.size(), kMinBoxWidth, load.slabs());
  if (comm.size() > 1) {
    EXPECT_NE(old_boxes, new_boxes);
  }
  const auto me = static_cast<std::size_t>(comm.rank());
  const MacGrid from(spec, old_boxes[me]);
  const MacGrid to(spec, new_boxes[me]);
  const GridMove move(from, to, old_boxes, new_boxes, comm);
  const auto code = [](int c, int i, int j, int k) {
    return 1e6 * (c + 2) + i + 100.0 * j + 1e4 * k;
  };
  // Apply f to every owned point of a grid's box (global indices).
  const auto for_owned = [](const MacGrid& g, int c, auto&& f) {
    std::array<std::array<int, 2>, 3> r{};
    for (int a = 0; a < 3; ++a) r[static_cast<std::size_t>(a)] = owned_points(g, g.box(), a, c);
    for (int k = r[2][0]; k < r[2][1]; ++k)
      for (int j = r[1][0]; j < r[1][1]; ++j)
        for (int i = r[0][0]; i < r[0][1]; ++i) f(i, j, k);
  };
  std::int64_t owned = 0;
  for (int c = kCellCentred; c < 3; ++c) {
    GridField a = from.make_field(-2.0), b = to.make_field(-1.0);
    const auto& lo = from.box().lo;
    for_owned(from, c, [&](int i, int j, int k) {
      a(i - lo[0], j - lo[1], k - lo[2]) = code(c, i, j, k);
    });
    move.move(a, b, c);
    const auto& nlo = to.box().lo;
    std::int64_t wrong = 0, n = 0;
    for_owned(to, c, [&](int i, int j, int k) {
      wrong += b(i - nlo[0], j - nlo[1], k - nlo[2]) != code(c, i, j, k);
      b(i - nlo[0], j - nlo[1], k - nlo[2]) = -1.0;
      ++n;
    });
    const auto untouched = static_cast<std::int64_t>(
        std::count(b.values().begin(), b.values().end(), -1.0));
    EXPECT_EQ(wrong, 0) << "centring " << c;
    EXPECT_EQ(untouched, static_cast<std::int64_t>(b.values().size())) << "a ghost was written";
    owned += n;
  }
  // Owned points over the ranks: each point of the grid exactly once (cells, then the faces:
  // periodic x has n faces, the walled axes n + 1).
  const std::int64_t n0 = 12, n1 = 16, n2 = 6;
  EXPECT_EQ(comm.sum(owned), n0 * n1 * n2 + n0 * n1 * n2 + n0 * (n1 + 1) * n2 +
                                n0 * n1 * (n2 + 1));
}

} // namespace
} // namespace cfddem::fluid
