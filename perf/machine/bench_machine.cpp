// What it costs two cores to share data, on the machine at hand: the explanation of why every
// per-particle pass keeps each particle on one thread (static partitions, the contact scatter
// by particle ranges: docs/parallel.md, "Threads"). Two threads pinned to cores 0 and 1.
//
// BM_LineRoundTrip: one cache line handed back and forth (an atomic counter each core bumps in
// turn); time per round trip.
// BM_ColumnPass/swapped:S/n:N: two columns of N doubles; each step core t updates its half of x,
// then (after a barrier) its half of v from x, S = 0, or the other core's half, S = 1. The second
// case is what a work-stealing partition does to a particle pass half the time.
#include <benchmark/benchmark.h>

#include <atomic>
#include <barrier>
#include <cstddef>
#include <cstdint>
#include <thread>
#include <vector>

#include <pthread.h>
#include <sched.h>

namespace {

bool pin(int core) {
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(core, &set);
  return pthread_setaffinity_np(pthread_self(), sizeof(set), &set) == 0;
}

void BM_LineRoundTrip(benchmark::State& state) {
  if (std::thread::hardware_concurrency() < 2) {
    state.SkipWithError("needs two cores");
    return;
  }
  alignas(64) std::atomic<std::int64_t> turn{0};
  std::atomic<bool> stop{false};
  std::thread other([&] {
    pin(1);
    std::int64_t expect = 1;
    while (!stop.load(std::memory_order_relaxed)) {
      if (turn.load(std::memory_order_acquire) == expect) {
        turn.store(expect + 1, std::memory_order_release);
        expect += 2;
      }
    }
  });
  pin(0);
  std::int64_t next = 0;
  for (auto _ : state) {
    turn.store(next + 1, std::memory_order_release);
    while (turn.load(std::memory_order_acquire) != next + 2) {
    }
    next += 2;
  }
  stop = true;
  other.join();
}
BENCHMARK(BM_LineRoundTrip)->UseRealTime();

void BM_ColumnPass(benchmark::State& state) {
  if (std::thread::hardware_concurrency() < 2) {
    state.SkipWithError("needs two cores");
    return;
  }
  const bool swapped = state.range(0) != 0;
  const auto n = static_cast<std::size_t>(state.range(1));
  std::vector<double> x(n, 1.0), v(n, 0.5);
  constexpr int kSteps = 50;
  auto steps = [&](int t, std::barrier<>& sync) {
    pin(t);
    const std::size_t a = n * t / 2, b = n * (t + 1) / 2;
    const int u = swapped ? 1 - t : t;
    const std::size_t c = n * u / 2, d = n * (u + 1) / 2;
    for (int s = 0; s < kSteps; ++s) {
      for (std::size_t i = a; i < b; ++i)
        x[i] += v[i] * 1e-6;
      sync.arrive_and_wait();
      for (std::size_t i = c; i < d; ++i)
        v[i] += x[i] * 1e-9;
      sync.arrive_and_wait();
    }
  };
  for (auto _ : state) {
    std::barrier<> sync(2);
    std::thread other([&] { steps(1, sync); });
    steps(0, sync);
    other.join();
  }
  benchmark::DoNotOptimize(v.data());
  state.SetItemsProcessed(state.iterations() * kSteps * static_cast<std::int64_t>(n));
}
BENCHMARK(BM_ColumnPass)
    ->ArgsProduct({{0, 1}, {100000, 1000000}})
    ->ArgNames({"swapped", "n"})
    ->UseRealTime()
    ->Unit(benchmark::kMicrosecond);

} // namespace
