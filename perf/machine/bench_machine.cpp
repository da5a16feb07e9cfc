// What it costs two cores to share data, on the machine at hand: the explanation of why every
// per-particle pass keeps each particle on one thread (static partitions, the contact scatter
// by particle ranges: docs/parallel.md, "Threads"). Two threads pinned to cores 0 and 1.
//
// BM_LineRoundTrip: one cache line handed back and forth (an atomic counter each core bumps in
// turn); time per round trip.
// BM_ColumnPass/swapped:S/n:N: two columns of N doubles; each step core t updates its half of x,
// then (after a barrier) its half of v from x, S = 0, or the other core's half, S = 1. The second
// case is what a work-stealing partition does to a particle pass half the time.
// BM_KickDriftStream/threads:T/n:N: the explicit update pass's kernel alone, its kick-drift
// v += ((f + e) m^-1 + g) dt, x += v dt over N particles (13 columns read, 6 written), on T = 1
// or 2 pinned threads, each its own half at every step (a static partition), a barrier between
// steps. It runs the instruction set copy simd_level() picks (CFDDEM_SIMD=x86-64 for the
// baseline one): with SSE2 one core is held by the loop's instructions, with AVX-512 by what its
// caches deliver. Two threads at less than twice one's rate: the caches and memory the cores
// share hold the pass, and no partition can do better.
#include <benchmark/benchmark.h>

#include <atomic>
#include <barrier>
#include <cstddef>
#include <cstdint>
#include <thread>
#include <vector>

#include <pthread.h>
#include <sched.h>

#include "dem/kick_drift_range.hpp"

namespace {

using namespace cfddem;

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

void BM_KickDriftStream(benchmark::State& state) {
  const auto threads = static_cast<int>(state.range(0));
  if (threads > 1 && std::thread::hardware_concurrency() < 2) {
    state.SkipWithError("needs two cores");
    return;
  }
  const auto n = static_cast<std::size_t>(state.range(1));
  // x, y, z, vx, vy, vz (read and written), fx, fy, fz, ex, ey, ez, 1/m (read): the update
  // pass's own kernel (dem/kick_drift_range.hpp) as it runs while the travel bound spares the
  // displacement test (no reference positions read), with the speed test.
  std::vector<std::vector<double>> col(13, std::vector<double>(n, 1e-3));
  const dem::KickDriftColumns all{col[0],  col[1], col[2], col[3], col[4],  col[5],
                                  col[6],  col[7], col[8], col[9], col[10], col[11],
                                  col[12], {},     {},     {},     {}};
  dem::KickDriftStep step;
  step.s = step.h = 1e-7, step.g = {0.0, -9.81, 0.0}, step.vmax2 = 1.0, step.cap2 = 1.0;
  constexpr int kSteps = 50;
  auto steps = [&](int t, std::barrier<>& sync) {
    pin(t);
    const dem::KickDriftColumns mine = all.range(n * t / threads, n * (t + 1) / threads);
    dem::KickDriftFlags flags;
    for (int s = 0; s < kSteps; ++s) {
      dem::kick_drift_range<true, false, true, false>(mine, step, flags);
      sync.arrive_and_wait();
    }
    benchmark::DoNotOptimize(flags);
  };
  for (auto _ : state) {
    std::barrier<> sync(threads);
    std::thread other;
    if (threads > 1)
      other = std::thread([&] { steps(1, sync); });
    steps(0, sync);
    if (other.joinable())
      other.join();
  }
  benchmark::DoNotOptimize(col[0].data());
  state.SetItemsProcessed(state.iterations() * kSteps * static_cast<std::int64_t>(n));
  state.SetBytesProcessed(state.iterations() * kSteps * static_cast<std::int64_t>(n) * 19 * 8);
}
BENCHMARK(BM_KickDriftStream)
    ->ArgsProduct({{1, 2}, {14000, 100000, 1000000}})
    ->ArgNames({"threads", "n"})
    ->UseRealTime()
    ->Unit(benchmark::kMicrosecond);

} // namespace
