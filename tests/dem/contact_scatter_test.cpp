// The scatter of contacts into per-particle sums runs over ranges of particle indices as tasks
// (dem/contact_scatter.hpp). Its claim: every particle's force and torque are bit for bit what one
// serial walk over the blocks gives (head blocks in order, then tail blocks, each contact adding
// to i then j), for any range size and thread count; and the clear zeroes exactly the particles
// the blocks and the `also` list name. The oracle is that serial walk written out here.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <vector>

#include <tbb/task_arena.h>

#include "core/particle_store.hpp"
#include "dem/contact_scatter.hpp"
#include "dem/pair_contacts.hpp"
#include "dem_test_support.hpp"

namespace cfddem {
namespace {

constexpr std::size_t kParticles = 5000;

ParticleStore random_store(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  ParticleStore p;
  p.resize(kParticles);
  p.enable_rotation();
  for (std::size_t i = 0; i < kParticles; ++i) {
    p.radius[i] = 1.0 + 0.5 * u(rng);
    p.fx[i] = u(rng), p.fy[i] = u(rng), p.fz[i] = u(rng);
    p.tx[i] = u(rng), p.ty[i] = u(rng), p.tz[i] = u(rng);
  }
  return p;
}

// Blocks shaped as the pair passes write them. Head: rows in index order, each contact i < j with
// j mostly a little above i and now and then far above (a partner a plane of cells away). Tail:
// pairs across a periodic face, i low and j high, so a block spans the whole index range.
std::vector<dem::PairContacts> random_blocks(std::mt19937_64& rng, bool tail, bool friction) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<dem::PairContacts> blocks(tail ? 4 : 40);
  std::uint32_t row = 0;
  for (dem::PairContacts& c : blocks) {
    const std::size_t size = tail ? 30 : 1 + rng() % 200;
    c.reserve_more(size, friction);
    for (std::size_t s = 0; s < size; ++s) {
      std::uint32_t i, j;
      if (tail) {
        i = static_cast<std::uint32_t>(rng() % 300);
        j = static_cast<std::uint32_t>(kParticles - 1 - rng() % 300);
      } else {
        row = std::min<std::uint32_t>(row + static_cast<std::uint32_t>(rng() % 3), kParticles - 2);
        i = row;
        const std::uint32_t ahead = rng() % 8 == 0 ? 1 + rng() % 1500 : 1 + rng() % 20;
        j = std::min<std::uint32_t>(i + ahead, kParticles - 1);
      }
      c.i[c.size] = i, c.j[c.size] = j;
      c.ax[c.size] = u(rng), c.ay[c.size] = u(rng), c.az[c.size] = u(rng);
      if (friction) {
        c.bx[c.size] = u(rng), c.by[c.size] = u(rng), c.bz[c.size] = u(rng);
        c.cx[c.size] = u(rng), c.cy[c.size] = u(rng), c.cz[c.size] = u(rng);
      }
      ++c.size;
    }
    c.bound_indices();
  }
  return blocks;
}

// One serial walk: what every range split must reproduce bit for bit.
void serial_scatter(ParticleStore& p, const std::vector<dem::PairContacts>& head,
                    const std::vector<dem::PairContacts>& tail, bool friction) {
  for (const auto* blocks : {&head, &tail})
    for (const dem::PairContacts& c : *blocks)
      for (std::size_t s = 0; s < c.size; ++s) {
        const std::uint32_t i = c.i[s], j = c.j[s];
        p.fx[i] -= c.ax[s], p.fy[i] -= c.ay[s], p.fz[i] -= c.az[s];
        p.fx[j] += c.ax[s], p.fy[j] += c.ay[s], p.fz[j] += c.az[s];
        if (friction) {
          p.fx[i] += c.bx[s], p.fy[i] += c.by[s], p.fz[i] += c.bz[s];
          p.fx[j] -= c.bx[s], p.fy[j] -= c.by[s], p.fz[j] -= c.bz[s];
          p.tx[i] += p.radius[i] * c.cx[s], p.ty[i] += p.radius[i] * c.cy[s],
              p.tz[i] += p.radius[i] * c.cz[s];
          p.tx[j] += p.radius[j] * c.cx[s], p.ty[j] += p.radius[j] * c.cy[s],
              p.tz[j] += p.radius[j] * c.cz[s];
        }
      }
}

using demtest::same_bits;

TEST(ContactScatter, RangeTasksSumInTheSerialOrder) {
  for (const bool friction : {false, true}) {
    std::mt19937_64 rng(friction ? 11 : 7);
    const ParticleStore start = random_store(rng);
    const auto head = random_blocks(rng, false, friction);
    const auto tail = random_blocks(rng, true, friction);
    ParticleStore want = start;
    serial_scatter(want, head, tail, friction);
    // Ranges of 7 to 5000 particles (one range: the serial path), on 1 and 4 threads.
    for (const int threads : {1, 4}) {
      for (const std::size_t range :
           {std::size_t{7}, std::size_t{97}, std::size_t{1000}, std::size_t{kParticles}}) {
        ParticleStore got = start;
        tbb::task_arena(threads).execute([&] {
          friction ? dem::scatter_contacts<true>(got, kParticles, head, tail, range)
                   : dem::scatter_contacts<false>(got, kParticles, head, tail, range);
        });
        SCOPED_TRACE(testing::Message()
                     << "friction " << friction << ", threads " << threads << ", range " << range);
        EXPECT_TRUE(same_bits(got.fx, want.fx) && same_bits(got.fy, want.fy) &&
                    same_bits(got.fz, want.fz));
        EXPECT_TRUE(same_bits(got.tx, want.tx) && same_bits(got.ty, want.ty) &&
                    same_bits(got.tz, want.tz));
        // The scatter changed something: the comparison is not of two untouched stores.
        EXPECT_FALSE(same_bits(got.fx, start.fx));
      }
    }
  }
}

TEST(ContactScatter, ClearZeroesExactlyTheNamedParticles) {
  std::mt19937_64 rng(3);
  const ParticleStore start = random_store(rng);
  const auto head = random_blocks(rng, false, true);
  const auto tail = random_blocks(rng, true, true);
  const std::vector<std::uint32_t> also = {0, 17, 2500, 2501, 4999};
  std::vector<bool> named(kParticles, false);
  for (const auto* blocks : {&head, &tail})
    for (const dem::PairContacts& c : *blocks)
      for (std::size_t s = 0; s < c.size; ++s)
        named[c.i[s]] = named[c.j[s]] = true;
  for (const std::uint32_t i : also)
    named[i] = true;
  for (const std::size_t range : {std::size_t{7}, std::size_t{1000}, std::size_t{kParticles}}) {
    ParticleStore got = start;
    tbb::task_arena(4).execute(
        [&] { dem::clear_contact_forces<true>(got, kParticles, head, tail, also, range); });
    std::size_t wrong = 0;
    for (std::size_t i = 0; i < kParticles; ++i) {
      const double f[6] = {got.fx[i], got.fy[i], got.fz[i], got.tx[i], got.ty[i], got.tz[i]};
      const double f0[6] = {start.fx[i], start.fy[i], start.fz[i],
                            start.tx[i], start.ty[i], start.tz[i]};
      for (int k = 0; k < 6; ++k)
        wrong += named[i] ? f[k] != 0.0 : f[k] != f0[k];
    }
    EXPECT_EQ(wrong, 0u) << "range " << range;
  }
}

} // namespace
} // namespace cfddem
