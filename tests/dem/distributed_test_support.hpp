// Shared set-up for the distributed DEM tests (explicit, friction, orb, islands over MPI ranks):
// a rank's share of a store as `cfddem run` deals it, the test-wide external force, the
// explicit run whose thread count must not change a bit, the worst differences of R ranks'
// particles from one rank's (the round-off comparisons), and a particle shot through a wall.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/communicator.hpp"
#include "core/error.hpp"
#include "core/initial_conditions.hpp"
#include "core/particle_store.hpp"
#include "core/phase_timer.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/step_model.hpp"
#include "dem_test_support.hpp"

namespace cfddem::demtest {

// Particle states by id: x, y, z, vx, vy, vz.
using StateById = std::map<std::int64_t, std::array<double, 6>>;

// The largest position difference (through a periodic face either way) and velocity difference
// of this rank's particles `mine` from the same ids in `one`, over all ranks; `count`: the
// particles of `mine` over all ranks (an id `one` lacks is a failure). Collective.
inline std::array<double, 2> worst_differences(const Scene& scene, const StateById& one,
                                               const StateById& mine, std::int64_t& count,
                                               const std::string& what) {
  const Communicator c = Communicator::world();
  const dem::DomainGeometry g(scene.domain);
  std::array<double, 2> worst{};
  for (const auto& [id, q] : mine) {
    const auto it = one.find(id);
    if (it == one.end()) {
      ADD_FAILURE() << what << ": unknown id " << id;
      continue;
    }
    for (int a = 0; a < 6; ++a) {
      double d = std::abs(q[a] - it->second[a]);
      if (a < 3)
        d = std::min(d, std::abs(d - g.length[a]));
      worst[a < 3 ? 0 : 1] = std::max(worst[a < 3 ? 0 : 1], d);
    }
  }
  count = c.sum(static_cast<std::int64_t>(mine.size()));
  c.max(worst);
  return worst;
}

// This rank's share of a store: every R-th particle (what `cfddem run` keeps before start()).
inline ParticleStore share(const ParticleStore& all, int rank, int ranks) {
  ParticleStore p = all;
  std::vector<std::uint32_t> pick;
  for (std::size_t i = static_cast<std::size_t>(rank); i < all.size();
       i += static_cast<std::size_t>(ranks))
    pick.push_back(static_cast<std::uint32_t>(i));
  p.permute(pick);
  return p;
}

// An external force per particle, a function of its id (the gas's force, held fixed): N.
inline std::array<double, 3> force_of(std::int64_t id) {
  return {1e-7 * static_cast<double>(id % 5 - 2), -2e-7 * static_cast<double>(id % 3),
          5e-8 * static_cast<double>(id % 7 - 3)};
}

// force_of for the first n particles of p, handed to the scheme.
inline void apply_force(const ParticleStore& p, std::size_t n, auto& scheme) {
  std::vector<double> fx(n), fy(n), fz(n);
  for (std::size_t i = 0; i < n; ++i) {
    const auto f = force_of(p.id[i]);
    fx[i] = f[0], fy[i] = f[1], fz[i] = f[2];
  }
  scheme.set_external_force(fx, fy, fz);
}

// `toml` with 20000 particles over at most 3 ranks (so the contact and update passes run as
// TBB loops), `steps` distributed explicit steps on `threads` threads: this rank's owned
// particles at the end. The run rebuilt its lists (checked), so migration happened.
inline ParticleStore run_explicit_with_threads(const char* toml, int threads, int steps) {
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  const Communicator c = Communicator::world();
  const Scene scene = scene_from(toml, {"particles.count=20000", "particles.temperature=1.0",
                                        "domain.hi=[4.71e-3, 4.71e-3, 4.71e-3]"});
  ParticleStore all = make_initial_particles(scene);
  const dem::StepModel model = dem::make_step_model(scene, all);
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  dem::ExplicitScheme s(scene, p, model, &c, timer);
  s.start();
  for (int k = 0; k < steps; ++k)
    s.step(k == steps - 1);
  EXPECT_GT(s.neighbor_builds(), 1);
  p.resize(s.owned());
  return p;
}

// A scheme (orb or islands over the world communicator) with particle `shot` of `scene`'s initial
// ones at 200 m/s along x (2 mm in a sub-iteration of 10 us, through the wall of a box about a
// millimetre wide): within `subits` sub-iterations every rank stops with the same RunError,
// which names the particle and the wall.
template <class Scheme>
void expect_shot_through_a_wall_stops_every_rank(const Scene& scene, int subits, std::size_t shot,
                                                 const std::string& what) {
  const Communicator c = Communicator::world();
  ParticleStore all = make_initial_particles(scene);
  all.vx[shot] = 200.0;
  ParticleStore p = share(all, c.rank(), c.size());
  PhaseTimer timer;
  Scheme s(scene, p, dem::make_step_model(scene, all), &c, timer);
  s.start();
  std::string message;
  try {
    for (int k = 0; k < subits; ++k)
      s.subiterate();
  } catch (const RunError& e) {
    message = e.what();
  }
  ASSERT_FALSE(message.empty()) << what << ": no rank stopped";
  EXPECT_NE(message.find("particle " + std::to_string(all.id[shot])), std::string::npos) << message;
  EXPECT_NE(message.find("left the domain through a wall"), std::string::npos) << message;
  // The same text on every rank (its hash, compared by a max and a min over the ranks).
  std::array<std::int64_t, 1> hi{static_cast<std::int64_t>(std::hash<std::string>{}(message))};
  std::array<std::int64_t, 1> lo = hi;
  c.max(hi);
  c.min(lo);
  EXPECT_EQ(hi[0], lo[0]) << message;
}

} // namespace cfddem::demtest
