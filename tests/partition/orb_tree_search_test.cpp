// Halo search on an ORB tree: leaves touching a query box and its periodic images.
#include "orb_test_support.hpp"

#include <set>
#include <tuple>

namespace cfddem::partition {
namespace {

using test::build;
using test::Cloud;
using test::uniform_cloud;

const Aabb kDomain{{0.0, -1.0, 0.0}, {2.0, 1.0, 1.0}};

using ImageSet = std::set<std::tuple<int, int, int, int>>; // leaf, shift x, y, z

// Every leaf against every image shift within +-3 domain lengths.
ImageSet brute_force_images(const OrbTree& t, const Aabb& q, std::array<bool, 3> periodic) {
  ImageSet out;
  const int r = 3;
  for (int sx = -r; sx <= r; ++sx) {
    for (int sy = -r; sy <= r; ++sy) {
      for (int sz = -r; sz <= r; ++sz) {
        const std::array<int, 3> s{sx, sy, sz};
        bool allowed = true;
        Aabb shifted = q;
        for (int a = 0; a < 3; ++a) {
          if (!periodic[a] && s[a] != 0) {
            allowed = false;
          }
          shifted.lo[a] += s[a] * kDomain.extent(a);
          shifted.hi[a] += s[a] * kDomain.extent(a);
        }
        if (!allowed) {
          continue;
        }
        for (const OrbLeaf& leaf : t.leaves()) {
          if (leaf.box.touches(shifted)) {
            out.insert({leaf.id, sx, sy, sz});
          }
        }
      }
    }
  }
  return out;
}

TEST(OrbTreeSearch, LeavesOverlappingMatchesBruteForce) {
  const Cloud c = uniform_cloud(3000, kDomain, 1);
  const OrbTree t = build(c, kDomain, {5, std::nullopt});
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    Aabb q;
    for (int a = 0; a < 3; ++a) {
      // Centres up to half a domain outside; half-widths up to 0.6 of the domain.
      const double centre = kDomain.lo[a] + (2.0 * u(rng) - 0.5) * kDomain.extent(a);
      const double half = 0.6 * u(rng) * kDomain.extent(a);
      q.lo[a] = centre - half;
      q.hi[a] = centre + half;
    }
    const std::array<bool, 3> periodic{(trial & 1) != 0, (trial & 2) != 0, (trial & 4) != 0};
    const ImageSet expected = brute_force_images(t, q, periodic);

    ImageSet got;
    for (const LeafImage& li : t.leaf_images_overlapping(q, periodic)) {
      const bool fresh = got.insert({li.leaf, li.shift[0], li.shift[1], li.shift[2]}).second;
      EXPECT_TRUE(fresh) << "duplicate image in trial " << trial;
    }
    EXPECT_EQ(got, expected) << "trial " << trial;

    std::set<int> ids;
    for (const auto& e : expected) {
      ids.insert(std::get<0>(e));
    }
    const std::vector<int> leaves = t.leaves_overlapping(q, periodic);
    EXPECT_EQ(std::vector<int>(ids.begin(), ids.end()), leaves) << "trial " << trial;
  }
}

TEST(OrbTreeSearch, HaloOfABoundaryLeafWrapsAroundPeriodicAxes) {
  const Cloud c = uniform_cloud(2000, kDomain, 3);
  const OrbTree t = build(c, kDomain, {4, std::nullopt});
  const OrbLeaf& first = t.leaves().front(); // touches the lo corner
  const Aabb halo = first.box.grown(0.05);
  const auto open = t.leaves_overlapping(halo, {false, false, false});
  const auto wrapped = t.leaves_overlapping(halo, {true, true, true});
  EXPECT_GT(wrapped.size(), open.size());
  // The leaf at the hi corner is a periodic neighbour of the lo corner leaf.
  EXPECT_TRUE(std::find(wrapped.begin(), wrapped.end(), t.leaves().back().id) != wrapped.end());
  EXPECT_TRUE(std::find(open.begin(), open.end(), first.id) != open.end());
}

TEST(OrbTreeSearch, QueryOutsideANonPeriodicDomainFindsNothing) {
  const Cloud c = uniform_cloud(500, kDomain, 4);
  const OrbTree t = build(c, kDomain, {3, std::nullopt});
  const Aabb q{{2.5, 0.0, 0.0}, {3.0, 0.5, 0.5}};
  EXPECT_TRUE(t.leaves_overlapping(q, {false, true, true}).empty());
  EXPECT_FALSE(t.leaves_overlapping(q, {true, false, false}).empty());
}

} // namespace
} // namespace cfddem::partition
