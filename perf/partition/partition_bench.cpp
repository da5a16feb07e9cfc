// ORB build over uniformly random points (L = 6, 64 leaves) and SFC ordering of box centres.
#include "partition/orb_tree.hpp"
#include "partition/space_filling_curve.hpp"

#include <benchmark/benchmark.h>

#include <random>
#include <vector>

namespace cfddem::partition {
namespace {

const Aabb kUnitCube{{0.0, 0.0, 0.0}, {1.0, 1.0, 1.0}};

void BM_OrbBuild(benchmark::State& state) {
  const auto n = static_cast<std::size_t>(state.range(0));
  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> x(n), y(n), z(n);
  for (std::size_t i = 0; i < n; ++i) {
    x[i] = u(rng);
    y[i] = u(rng);
    z[i] = u(rng);
  }
  const OrbOptions opt{6, std::nullopt};
  for (auto _ : state) {
    OrbTree t = OrbTree::build(x, y, z, {}, kUnitCube, opt);
    benchmark::DoNotOptimize(t.order().data());
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * state.range(0));
}
BENCHMARK(BM_OrbBuild)->RangeMultiplier(10)->Range(1000, 1000000)->Unit(benchmark::kMillisecond);

void BM_SfcOrder(benchmark::State& state) {
  const auto n = static_cast<std::size_t>(state.range(0));
  const auto kind = static_cast<CurveKind>(state.range(1));
  std::mt19937_64 rng(43);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<std::array<double, 3>> centres(n);
  for (auto& c : centres) {
    c = {u(rng), u(rng), u(rng)};
  }
  for (auto _ : state) {
    std::vector<std::uint32_t> order = sfc_order(centres, kUnitCube, kind);
    benchmark::DoNotOptimize(order.data());
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()) * state.range(0));
  state.SetLabel(kind == CurveKind::morton ? "morton" : "hilbert");
}
BENCHMARK(BM_SfcOrder)
    ->Args({10000, static_cast<int>(CurveKind::morton)})
    ->Args({10000, static_cast<int>(CurveKind::hilbert)})
    ->Unit(benchmark::kMicrosecond);

} // namespace
} // namespace cfddem::partition
