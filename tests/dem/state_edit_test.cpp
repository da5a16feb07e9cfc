// dem/state_edit.hpp: a saved state compacted to the particles that stay. The index maps
// and lists are checked by hand; then the explicit scheme with friction, with a loner removed
// halfway through a run, must step the rest bit for bit as the run that kept it (the loner never
// touches them nor moves, so it changes no force, no sum order and no rebuild).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

#include "dem/state_edit.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;
using cfddem::demtest::kPairScene;
using cfddem::demtest::scene_from;

TEST(Compaction, MapsRowsPairsAndHistoryToTheParticlesThatStay) {
  const std::vector<std::uint32_t> kept = {0, 2, 3};
  const dem::Compaction c(4, kept);
  EXPECT_EQ(c[0], 0u);
  EXPECT_EQ(c[1], dem::Compaction::kGone);
  EXPECT_EQ(c[3], 2u);

  std::vector<double> v = {10, 11, 12, 13};
  c.apply(v);
  EXPECT_EQ(v, (std::vector<double>{10, 12, 13}));
  std::vector<double> none;
  c.apply(none); // empty: no such array
  EXPECT_TRUE(none.empty());
  std::vector<double> wrong = {1, 2};
  EXPECT_THROW(c.apply(wrong), RunError);

  // Half-list rows: 0 -> {1, 2}, 1 -> {2, 3}, 2 -> {3}, 3 -> {}; one history value per entry.
  std::vector<std::uint32_t> off = {0, 2, 4, 5, 5}, nb = {1, 2, 2, 3, 3};
  std::vector<double> hx = {1, 2, 3, 4, 5};
  std::vector<double> hy; // frictionless: no history
  c.apply_rows(off, nb, {&hx, &hy});
  EXPECT_EQ(off, (std::vector<std::uint32_t>{0, 1, 2, 2}));
  EXPECT_EQ(nb, (std::vector<std::uint32_t>{1, 2})); // 0 -> old 2, old 2 -> old 3
  EXPECT_EQ(hx, (std::vector<double>{2, 5}));

  std::vector<std::uint32_t> a = {0, 1, 2}, b = {3, 2, 0};
  c.apply_pairs(a, b);
  EXPECT_EQ(a, (std::vector<std::uint32_t>{0, 1}));
  EXPECT_EQ(b, (std::vector<std::uint32_t>{2, 0}));

  dem::ContactHistory h;
  h.add(100, 101, 1, 0, 0);
  h.add(102, 103, 2, 0, 0);
  h.add(101, 102, 3, 0, 0);
  const std::vector<std::int64_t> ids = {100, 101, 102, 103};
  c.apply_history(h, ids);
  ASSERT_EQ(h.size(), 1u);
  EXPECT_EQ(h.owner[0], 102);
  EXPECT_EQ(h.partner[0], 103);

  const std::vector<std::uint32_t> unordered = {2, 1};
  EXPECT_THROW(dem::Compaction(4, unordered), std::invalid_argument);
}

namespace {

// A frictional pair that collides obliquely at 0.83 ms and a loner at rest far from both, over
// 1.2 ms; `remove`: the loner is removed during the contact. The pair's final state.
std::vector<double> pair_after(bool remove) {
  const Scene s = scene_from(kPairScene, {"dem.friction=0.3", "domain.periodic=[false,true,true]",
                                          "dem.wall_spring_constant=10"});
  ParticleStore p;
  p.add(2.0e-4, 5e-4, 5e-4, 0.3, 0.05, 0, 50e-6, 1000.0, 0);
  p.add(8.0e-4, 5.3e-4, 5e-4, -0.3, -0.05, 0, 50e-6, 1000.0, 1);
  p.add(5.0e-4, 5e-4, 1e-4, 0, 0, 0, 50e-6, 1000.0, 2); // the loner
  PhaseTimer timer;
  auto scheme = std::make_unique<dem::ExplicitScheme>(s, p, timer);
  scheme->start();
  // The gap of 0.5 mm closes at 0.6 m/s after 0.83 ms; the loner goes in the middle of the
  // contact (its 10th step), so that the pair's list entry and tangential spring must survive.
  const long steps = std::lround(1.2e-3 / scheme->dt());
  long contact_steps = 0;
  bool removed = false;
  for (long k = 0; k < steps; ++k) {
    if (remove && !removed && contact_steps == 10) {
      removed = true;
      dem::ExplicitScheme::State st = scheme->save_state();
      std::vector<std::uint32_t> kept;
      for (std::uint32_t i = 0; i < p.size(); ++i)
        if (p.id[i] != 2)
          kept.push_back(i);
      const dem::Compaction c(p.size(), kept);
      dem::erase_removed(st, c);
      scheme.reset();
      p.permute(kept);
      scheme = std::make_unique<dem::ExplicitScheme>(s, p, timer);
      scheme->restore_state(std::move(st));
    }
    scheme->step(false);
    contact_steps += std::ranges::any_of(p.fx, [](double f) { return f != 0.0; });
  }
  EXPECT_EQ(removed, remove);
  std::vector<double> out;
  for (std::int64_t id : {0, 1})
    for (std::size_t i = 0; i < p.size(); ++i)
      if (p.id[i] == id)
        out.insert(out.end(),
                   {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i], p.wx[i], p.wz[i]});
  return out;
}

} // namespace

TEST(ParticleRemoval, ExplicitSchemeStepsTheRestAsIfTheLonerWereStillThere) {
  const std::vector<double> kept = pair_after(false), removed = pair_after(true);
  ASSERT_EQ(kept.size(), 16u);
  EXPECT_EQ(kept, removed);
  // The pair did collide after the removal: particle 0 moves back, and spins about z (friction
  // acted on the oblique contact).
  EXPECT_LT(kept[3], 0.0);
  EXPECT_NE(kept[7], 0.0);
}
