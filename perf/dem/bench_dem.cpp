// Benchmarks of the explicit DEM kernels on homogeneous cooling gases like the peers' scenes:
// d = 100 um, rho = 1000 kg/m^3, T0 = 0.01 m^2/s^2, k = 10 N/m, e = 0.8, frictionless, periodic
// cube, skin 25 um, dt = tau/50. Arguments: {solid fraction in percent, particles}.
//   BM_NeighborBuild  VerletList::build (wrap, cell sort, permute the store, full CSR list)
//   BM_OrbSubiteration, BM_OrbLeafSubiteration, BM_OrbGhostRefresh: the orb scheme (below)
//   BM_ExplicitStep   ExplicitScheme::step (contact pass + update; rebuilds when the skin is used
//                     up, as in a run: the counter builds_per_step says how often)
//   BM_DenseStep      the same step on 100k particles at phi 0.1, 0.3 and 0.5 (issue 21's dense
//                     granular flow; force_s_per_step is the contact pass)
//   BM_DenseContactPass  the contact pass alone on those gases (pair passes over the half list's
//                     flat pair streams and the scatter to both particles; list and streams
//                     built once)
//   BM_ContactCensus  dem::take_census, taken at each diagnostics row (its cost against
//                     BM_ExplicitStep's: how many explicit steps one row's census costs)
// items_per_second = particles processed per second (particle-steps/s for the step).
// Threads: CFDDEM_BENCH_THREADS (default 1, to compare with the single-core peer figures).
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>
#include <numbers>
#include <utility>

#include <benchmark/benchmark.h>
#include <tbb/global_control.h>

#include "core/initial_conditions.hpp"
#include "core/phase_timer.hpp"
#include "core/scene.hpp"
#include "dem/contact_census.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/explicit_scheme.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/orb_scheme.hpp"
#include "dem/step_model.hpp"
#include "dem/verlet_list.hpp"
#include "dem/verlet_passes.hpp"

namespace {

using namespace cfddem;

constexpr double kDiameter = 100e-6, kDensity = 1000.0, kSkin = 25e-6;

Scene gas_scene(double phi, std::int64_t n) {
  Scene s;
  s.name = "bench_gas";
  const double box = std::cbrt(static_cast<double>(n) * std::numbers::pi * kDiameter * kDiameter *
                               kDiameter / (6.0 * phi));
  s.domain.lo = {0, 0, 0};
  s.domain.hi = {box, box, box};
  s.domain.periodic = {true, true, true};
  auto& p = s.particles;
  p.count = n;
  p.diameter = kDiameter;
  p.density = kDensity;
  p.temperature = 0.01;
  // Random sequential addition jams near 0.38: denser gases start on the cubic lattice (up to
  // pi/6 = 0.52) with the same thermal velocities.
  p.placement = phi < 0.35 ? "random" : "lattice";
  p.region_lo = s.domain.lo;
  p.region_hi = s.domain.hi;
  p.seed = 7;
  auto& d = s.dem;
  d.spring_constant = d.wall_spring_constant = 10.0;
  d.restitution = d.wall_restitution = 0.8;
  d.friction = d.wall_friction = 0.0;
  d.dt_factor = 0.02;
  d.neighbor_skin = kSkin;
  s.run.end_time = 1.0;
  s.output.interval = 1.0;
  return s;
}

// Initial gases are made once per (phi, n) and copied into each benchmark.
struct Gas {
  Scene scene;
  ParticleStore particles;
};
const Gas& gas(int phi_percent, std::int64_t n) {
  static std::map<std::pair<int, std::int64_t>, std::unique_ptr<Gas>> cache;
  auto& g = cache[{phi_percent, n}];
  if (!g) {
    g = std::make_unique<Gas>();
    g->scene = gas_scene(phi_percent / 100.0, n);
    g->particles = make_initial_particles(g->scene);
  }
  return *g;
}

tbb::global_control threads_from_env() {
  const char* t = std::getenv("CFDDEM_BENCH_THREADS");
  const int n = t ? std::max(1, std::atoi(t)) : 1;
  return tbb::global_control(tbb::global_control::max_allowed_parallelism,
                             static_cast<std::size_t>(n));
}

void BM_NeighborBuild(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  ParticleStore p = g.particles;
  const dem::DomainGeometry geom(g.scene.domain);
  dem::VerletList list;
  list.build(p, geom, kSkin); // first build sorts the store, as in a run
  for (auto _ : state) {
    list.build(p, geom, kSkin);
    benchmark::DoNotOptimize(list.neighbors().data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(p.size()));
  state.counters["pairs_per_particle"] =
      static_cast<double>(list.pair_count()) / static_cast<double>(p.size());
}

void BM_ExplicitStep(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  ParticleStore p = g.particles;
  PhaseTimer timer;
  dem::ExplicitScheme scheme(g.scene, p, timer);
  scheme.start();
  timer = PhaseTimer{}; // count the loop only
  const auto builds0 = scheme.neighbor_builds();
  for (auto _ : state) {
    scheme.step();
    benchmark::DoNotOptimize(p.x.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(p.size()));
  state.counters["builds_per_step"] =
      static_cast<double>(scheme.neighbor_builds() - builds0) /
      static_cast<double>(std::max<std::int64_t>(1, state.iterations()));
  state.counters["force_s_per_step"] =
      benchmark::Counter(timer.seconds(Phase::force), benchmark::Counter::kAvgIterations);
  state.counters["neighbor_s_per_step"] =
      benchmark::Counter(timer.seconds(Phase::neighbor), benchmark::Counter::kAvgIterations);
}

void BM_DenseContactPass(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  ParticleStore p = g.particles;
  const dem::DomainGeometry geom(g.scene.domain);
  const dem::StepModel m = dem::make_step_model(g.scene, p);
  dem::VerletList list;
  list.build(p, geom, kSkin, dem::RowKind::half);
  std::vector<dem::PairContacts> head, tail;
  std::size_t nh = 0, nt = 0;
  dem::PairStream sh, st;
  sh.build<false>(list, list.active(), dem::kPairBlock, false);
  st.build<true>(list, list.tail_rows(), dem::kPairBlock, false);
  for (auto _ : state) {
    dem::StepReport rep;
    dem::clear_forces<false>(p, list.listed_index());
    nh = dem::pair_pass<false, false>(p, sh, {}, geom, m, m.dt, head, rep);
    nt = dem::pair_pass<false, true>(p, st, {}, geom, m, m.dt, tail, rep);
    dem::scatter_contacts<false>(p, p.size(), std::span<const dem::PairContacts>(head).first(nh),
                                 std::span<const dem::PairContacts>(tail).first(nt));
    benchmark::DoNotOptimize(p.fx.data());
  }
  std::size_t contacts = 0;
  for (std::size_t b = 0; b < nh; ++b)
    contacts += head[b].size;
  for (std::size_t b = 0; b < nt; ++b)
    contacts += tail[b].size;
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(p.size()));
  state.counters["pairs_per_particle"] =
      static_cast<double>(list.pair_count()) / static_cast<double>(p.size());
  state.counters["contacts_per_particle"] =
      static_cast<double>(contacts) / static_cast<double>(p.size());
}

// The orb scheme on the same gases, 2^levels leaves of ~19 particles (the paper's HCS 1222 in
// 64 leaves): one whole sub-iteration (dt_sp = 1e-5 s, ~70 fine steps per fine leaf), one leaf's
// fine sub-iteration alone, and the ghost refresh (frozen copies + own/other-leaf rows). The
// whole sub-iteration takes the global mode where it triggers; the leaf benchmarks measure the
// leaf steps (`leaf`: dem.orb_global = false).
int levels_for(std::int64_t n) {
  int L = 0;
  while ((std::int64_t{19} << (L + 1)) <= n)
    ++L;
  return L;
}
Scene orb_scene(const Gas& g, std::int64_t n, bool leaf = false) {
  Scene s = g.scene;
  s.dem.scheme = "orb";
  s.dem.orb_global = !leaf;
  s.dem.nsubit = 10;
  s.partition.orb_levels = levels_for(n);
  return s;
}

void BM_OrbSubiteration(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  const Scene s = orb_scene(g, state.range(1));
  ParticleStore p = g.particles;
  PhaseTimer timer;
  dem::OrbScheme scheme(s, p, timer);
  scheme.start();
  scheme.subiterate();
  const auto steps0 = scheme.particle_steps();
  for (auto _ : state) {
    scheme.subiterate();
    benchmark::DoNotOptimize(p.x.data());
  }
  state.SetItemsProcessed(scheme.particle_steps() - steps0);
  state.counters["leaves"] = scheme.leaf_count();
  state.counters["fine_leaf_fraction"] = scheme.last_fine_fraction();
}

// One sub-iteration of the islands scheme (dt_sp = 1e-5 s, as the orb benchmark): links,
// islands, free flight and the islands' fine steps. Items: particle steps (a free particle's one
// step of dt_sp counts once).
void BM_IslandsSubiteration(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  Scene s = g.scene;
  s.dem.scheme = "islands";
  s.dem.nsubit = 10;
  ParticleStore p = g.particles;
  PhaseTimer timer;
  dem::IslandsScheme scheme(s, p, timer);
  scheme.start();
  scheme.subiterate();
  const auto steps0 = scheme.particle_steps();
  for (auto _ : state) {
    scheme.subiterate();
    benchmark::DoNotOptimize(p.x.data());
  }
  state.SetItemsProcessed(scheme.particle_steps() - steps0);
  state.counters["fine_fraction"] = scheme.last_fine_fraction();
}

void BM_OrbLeafSubiteration(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  const Scene s = orb_scene(g, state.range(1), true);
  ParticleStore p = g.particles;
  PhaseTimer timer;
  dem::OrbScheme scheme(s, p, timer);
  scheme.start();
  scheme.subiterate();
  const ParticleStore saved = p;
  const int leaf = scheme.leaf_count() / 2;
  for (auto _ : state) {
    scheme.benchmark_leaf_subiteration(leaf);
    benchmark::DoNotOptimize(p.x.data());
    state.PauseTiming();
    p = saved; // the same leaf state every iteration
    state.ResumeTiming();
  }
  state.counters["leaf_particles"] =
      static_cast<double>(p.size()) / static_cast<double>(scheme.leaf_count());
}

void BM_OrbGhostRefresh(benchmark::State& state) {
  const auto threads = threads_from_env();
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  const Scene s = orb_scene(g, state.range(1), true);
  ParticleStore p = g.particles;
  PhaseTimer timer;
  dem::OrbScheme scheme(s, p, timer);
  scheme.start();
  scheme.subiterate();
  for (auto _ : state) {
    scheme.benchmark_ghost_refresh();
    benchmark::DoNotOptimize(p.fx.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(p.size()));
}

void BM_ContactCensus(benchmark::State& state) {
  const Gas& g = gas(static_cast<int>(state.range(0)), state.range(1));
  const ParticleStore& p = g.particles;
  const dem::DomainGeometry geom(g.scene.domain);
  const dem::CensusLaws laws{10.0, 0.8, 10.0, 0.8};
  std::int64_t contacts = 0;
  for (auto _ : state) {
    const dem::ContactCensus c = dem::take_census({p.x, p.y, p.z, p.radius, p.mass}, geom, laws);
    contacts = c.pair_contacts;
    benchmark::DoNotOptimize(contacts);
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(p.size()));
  state.counters["contacts"] = static_cast<double>(contacts);
}

void gases(benchmark::internal::Benchmark* b) {
  for (int phi : {1, 30})
    for (std::int64_t n : {1000, 10000, 100000})
      b->Args({phi, n});
  b->ArgNames({"phi_pct", "n"});
}

} // namespace

BENCHMARK(BM_NeighborBuild)->Apply(gases)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ExplicitStep)->Apply(gases)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ContactCensus)->Apply(gases)->Unit(benchmark::kMicrosecond);
// Dense granular flow: the explicit step at solid fractions 10, 30, 50% on 100k particles.
void BM_DenseStep(benchmark::State& state) {
  BM_ExplicitStep(state);
}
BENCHMARK(BM_DenseStep)
    ->ArgNames({"phi_pct", "n"})
    ->Args({10, 100000})
    ->Args({30, 100000})
    ->Args({50, 100000})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_DenseContactPass)
    ->ArgNames({"phi_pct", "n"})
    ->Args({10, 100000})
    ->Args({30, 100000})
    ->Args({50, 100000})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_OrbSubiteration)->Apply(gases)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_IslandsSubiteration)->Apply(gases)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_OrbLeafSubiteration)->Apply(gases)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_OrbGhostRefresh)->Apply(gases)->Unit(benchmark::kMicrosecond);
