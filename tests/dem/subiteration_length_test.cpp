// dem.nsubit = "auto" (dem/subiteration_length.hpp, the islands scheme's control interval): the
// first-contact histogram counts what the link test will link, the choice finds the analytic
// optimum of its cost model, and in the scheme the choice follows the scene (a denser gas takes
// shorter sub-iterations), misses no collision, and is bitwise the same for any thread count and
// across a save/restore.
#include <cmath>
#include <cstdint>
#include <numbers>
#include <string>
#include <unordered_map>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include "core/error.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/scheme_support.hpp"
#include "dem/subiteration_length.hpp"
#include "dem_test_support.hpp"

using namespace cfddem;
namespace length = cfddem::dem::length;
using cfddem::dem::DomainGeometry;

namespace {

DomainSpec periodic_box(double L) {
  DomainSpec d;
  d.lo = {0, 0, 0};
  d.hi = {L, L, L};
  d.periodic = {true, true, true};
  return d;
}

// Two particles of radius r on the x axis, gap `gap`, rows holding each other.
struct Pair {
  std::vector<std::uint32_t> off{0, 1, 2}, nb{1, 0};
  std::vector<double> x, y{0.5e-3, 0.5e-3}, z{0.5e-3, 0.5e-3}, r{50e-6, 50e-6}, s;
  Pair(double gap, double speed) : x{0.4e-3, 0.4e-3 + 100e-6 + gap}, s{speed, speed} {}
  length::RowsView view() const {
    return {off, nb, x.data(), y.data(), z.data(), r.data(), s.data(), 2};
  }
};

} // namespace

// A pair closing from gap g at bound s each links over dt when g - margin < 2 s dt: fine for the
// m with D / m > tau = (g - margin) / (2 s), i.e. m <= ceil(D / tau) - 1.
TEST(SubiterationLength, FirstContactHistogramCountsTheLinkTest) {
  const DomainGeometry g(periodic_box(1e-3));
  const double D = 1e-4, margin = 1e-8;
  const std::int64_t m_hi = 1000;
  {
    const Pair p(10e-6, 0.1); // tau = (1e-5 - 1e-8) / 0.2 = 4.995e-5 s: m < 2.002
    std::vector<std::int64_t> h(m_hi + 1, 0);
    length::first_contact_histogram(p.view(), g, margin, D, m_hi, h);
    EXPECT_EQ(h[2], 2); // m = 1, 2 (dt_sp = 1e-4, 5e-5 > tau), both particles
    std::int64_t total = 0;
    for (auto c : h)
      total += c;
    EXPECT_EQ(total, 2);
    // What the link test says at the two lengths around tau.
    const double d2 = std::pow(100e-6 + 10e-6, 2);
    EXPECT_TRUE(dem::islands::may_touch(d2, 0.1, 0.1, 50e-6, 50e-6, D / 2, margin));
    EXPECT_FALSE(dem::islands::may_touch(d2, 0.1, 0.1, 50e-6, 50e-6, D / 3, margin));
  }
  {
    const Pair p(-1e-6, 0.0); // overlapping: fine at every length
    std::vector<std::int64_t> h(m_hi + 1, 0);
    length::first_contact_histogram(p.view(), g, margin, D, m_hi, h);
    EXPECT_EQ(h[m_hi], 2);
  }
  {
    const Pair p(200e-6, 0.5); // tau = 2e-4 s > D: never fine
    std::vector<std::int64_t> h(m_hi + 1, 0);
    length::first_contact_histogram(p.view(), g, margin, D, m_hi, h);
    for (auto c : h)
      EXPECT_EQ(c, 0);
  }
}

// First-contact times spread evenly, B(dt) = N dt / T: the cost per interval m (c_o N + c_f N
// dt / T * dt / dt_f) with dt = D / m is least at m* = D sqrt(c_f / (c_o T dt_f)); the choice
// must find it (within the rounding of K = ceil(dt / dt_f)), shorter sub-iterations for a shorter
// T (a denser or hotter gas), and the longest allowed when nothing comes near.
TEST(SubiterationLength, ChoiceFindsTheModelsOptimum) {
  const double D = 1e-4, dt_f = 1e-7, N = 1e5;
  const std::int64_t m_hi = length::most_subiterations(D, dt_f);
  ASSERT_EQ(m_hi, 1000);
  // B(D / m) = N D / (m T): a particle with first-contact time tau is fine for m < D / tau.
  auto spread = [&](double T) {
    std::vector<double> h(static_cast<std::size_t>(m_hi) + 1, 0.0);
    for (std::int64_t m = 1; m <= m_hi; ++m) {
      const double b = std::min(N, N * D / (static_cast<double>(m) * T));
      const double b_next = std::min(N, N * D / (static_cast<double>(m + 1) * T));
      h[static_cast<std::size_t>(m)] = m == m_hi ? b : b - b_next;
    }
    return h;
  };
  std::int64_t m_before = 0;
  for (const double T : {2e-2, 2e-3, 2e-4}) { // m* = 3.9, 12.5, 39.4
    const double m_star = D * std::sqrt(length::kPerFineStep / (length::kPerParticle * T * dt_f));
    const length::Choice c = length::choose(spread(T), N, D, dt_f, 1.0, 1, m_hi, 1, length::kSkin);
    EXPECT_NEAR(static_cast<double>(c.m), m_star, 0.1 * m_star + 1.0) << "T = " << T;
    EXPECT_EQ(c.reason, length::kMinCost);
    EXPECT_GT(c.m, m_before); // shorter T: shorter sub-iterations
    m_before = c.m;
  }
  std::vector<double> none(static_cast<std::size_t>(m_hi) + 1, 0.0);
  EXPECT_EQ(length::choose(none, N, D, dt_f, 1.0, 3, m_hi, 10, length::kSkin).m, 3);
  // Next to the optimum the previous count is kept (the best saves less than kMinGain); far
  // from it the count changes.
  const length::Choice kept = length::choose(spread(2e-3), N, D, dt_f, 1.0, 1, m_hi, 14, 0);
  EXPECT_EQ(kept.m, 14);
  EXPECT_EQ(kept.reason, length::kKept);
  const length::Choice moved = length::choose(spread(2e-3), N, D, dt_f, 1.0, 1, m_hi, 40, 0);
  EXPECT_NEAR(static_cast<double>(moved.m), 12.5, 2.5);
  EXPECT_LT(moved.cost_ratio, 1.0 - length::kMinGain);
  // rho scales the fine count: 4x the fine particles move the optimum by sqrt(4).
  const length::Choice more = length::choose(spread(2e-3), N, D, dt_f, 4.0, 1, m_hi, 1, 0);
  EXPECT_NEAR(static_cast<double>(more.m), 25.0, 3.5);
}

// The rows' entries price each sub-iteration too: with entries whose link cost is three times
// the per-particle cost, the overhead per sub-iteration is 4x and the optimum
// m* = D sqrt(c_f / (c_o T dt_f)) halves. row_entries is N^2 / V (4/3) pi (2 r + s)^3.
TEST(SubiterationLength, RowEntriesPriceEachSubiteration) {
  const double D = 1e-4, dt_f = 1e-7, N = 1e5, T = 2e-4;
  const std::int64_t m_hi = length::most_subiterations(D, dt_f);
  std::vector<double> h(static_cast<std::size_t>(m_hi) + 1, 0.0);
  for (std::int64_t m = 1; m <= m_hi; ++m) {
    const double b = std::min(N, N * D / (static_cast<double>(m) * T));
    const double b_next = std::min(N, N * D / (static_cast<double>(m + 1) * T));
    h[static_cast<std::size_t>(m)] = m == m_hi ? b : b - b_next;
  }
  const double entries = 3.0 * length::kPerParticle * N / length::kPerEntry;
  const length::Choice plain = length::choose(h, N, D, dt_f, 1.0, 1, m_hi, 1, 0);
  const length::Choice priced = length::choose(h, N, D, dt_f, 1.0, 1, m_hi, 1, 0, entries);
  EXPECT_NEAR(static_cast<double>(priced.m), 0.5 * static_cast<double>(plain.m),
              0.1 * static_cast<double>(plain.m) + 1.0);
  // 600 spheres of 50 um in a 1 mm box with a 75 um skin: 13.5 partners each (measured 12.5).
  EXPECT_NEAR(length::row_entries(600, 1e-9, 50e-6, 75e-6) / 600.0,
              600.0 / 1e-9 * 4.0 / 3.0 * std::numbers::pi * std::pow(175e-6, 3), 1e-9);
  EXPECT_NEAR(length::row_entries(600, 1e-9, 50e-6, 75e-6) / 600.0, 13.5, 0.05);
}

// The global mode (every particle on the fine step through the explicit scheme's passes, no
// bounds or links) is a candidate: it costs K(D) N (kGlobalPerStep + kGlobalPerPair pairs) /
// kGlobalRate against the islands' m [kPerParticle N + kPerEntry entries + kPerFineStep B K]. A
// dense gas where everyone is fine at every m takes it; a dilute one keeps its islands; once in it,
// it is kept unless an islands' count saves kMinGain.
TEST(SubiterationLength, ChoiceTakesTheGlobalModeWhereIslandsCostMore) {
  const double D = 1e-4, dt_f = 1e-7, N = 600;
  const std::int64_t m_hi = length::most_subiterations(D, dt_f);
  std::vector<double> dense(static_cast<std::size_t>(m_hi) + 1, 0.0);
  dense[static_cast<std::size_t>(m_hi)] = N; // in contact: fine at every m
  const double entries = length::row_entries(N, 1e-9, 50e-6, 75e-6);
  const double pairs = 0.5 * length::row_entries(N, 1e-9, 50e-6, 25e-6) / N;
  // Islands at their best, m = 1: one sub-iteration of 1000 fine steps for all 600, priced at
  // kPerFineStep per particle step; the global mode prices the same steps at (38 + 34 x 2.45) /
  // 1.5.
  const length::Choice isl =
      length::choose(dense, N, D, dt_f, 1.0, 1, m_hi, 1, length::kSkin, entries);
  EXPECT_FALSE(isl.global);
  const length::Choice g =
      length::choose(dense, N, D, dt_f, 1.0, 1, m_hi, 1, length::kSkin, entries, pairs);
  EXPECT_TRUE(g.global);
  EXPECT_EQ(g.m, 1);
  EXPECT_EQ(g.reason, length::kGlobal);
  EXPECT_NEAR(g.cost_ratio,
              (length::kGlobalPerStep + length::kGlobalPerPair * pairs) / length::kGlobalRate /
                  (length::kPerFineStep +
                   (length::kPerParticle + length::kPerEntry * entries / N) / 1000.0),
              1e-9);
  // Kept while in it: the islands' best at m = 1 is dearer.
  const length::Choice kept =
      length::choose(dense, N, D, dt_f, 1.0, 1, m_hi, 1, length::kSkin, entries, pairs, true);
  EXPECT_TRUE(kept.global);
  EXPECT_EQ(kept.reason, length::kKept);
  // A dilute gas (the spread of ChoiceFindsTheModelsOptimum, N = 1e5, T = 2e-3): the islands
  // cost a fraction of the global mode, which it leaves.
  std::vector<double> spread(static_cast<std::size_t>(m_hi) + 1, 0.0);
  const double Nd = 1e5, T = 2e-3;
  for (std::int64_t m = 1; m <= m_hi; ++m) {
    const double b = std::min(Nd, Nd * D / (static_cast<double>(m) * T));
    const double b_next = std::min(Nd, Nd * D / (static_cast<double>(m + 1) * T));
    spread[static_cast<std::size_t>(m)] = m == m_hi ? b : b - b_next;
  }
  const length::Choice left =
      length::choose(spread, Nd, D, dt_f, 1.0, 1, m_hi, 1, length::kSkin, 0.0, 0.078, true);
  EXPECT_FALSE(left.global);
  EXPECT_EQ(left.reason, length::kMinCost);
  EXPECT_LT(left.cost_ratio, 0.2);
}

TEST(SubiterationLength, BoundsOnTheCount) {
  EXPECT_EQ(length::most_subiterations(1e-4, 1e-7), 1000);
  EXPECT_EQ(length::most_subiterations(1e-4, 3e-4), 1);
  // 2 s_max D / m <= skin / 2.
  EXPECT_EQ(length::fewest_for_skin(1e-4, 1.0, 7.5e-5), 6); // 4 * 1e-4 / 7.5e-5 = 5.33
  EXPECT_EQ(length::fewest_for_skin(1e-4, 0.0, 7.5e-5), 1);
  // dA / m <= 0.1 a_ref.
  EXPECT_EQ(length::fewest_for_gas(5.0, 10.0), 5);
  EXPECT_EQ(length::fewest_for_gas(0.0, 10.0), 1);
}

namespace {

const char* kAutoGas = R"(
[domain]
lo = [0.0, 0.0, 0.0]
hi = [2.757e-3, 2.757e-3, 2.757e-3]
periodic = [true, true, true]
[particles]
count = 400
diameter = 100.0e-6
density = 1000.0
temperature = 0.01
seed = 5
[dem]
scheme = "islands"
spring_constant = 10.0
restitution = 0.8
dt = 1.0e-7
nsubit = "auto"
regrid_interval = 1.0e-4
[run]
end_time = 1.0
)";

using State = std::unordered_map<std::int64_t, std::array<double, 7>>;

State state_of(const ParticleStore& p, const std::vector<double>& hprev) {
  State s;
  for (std::size_t i = 0; i < p.size(); ++i)
    s[p.id[i]] = {p.x[i], p.y[i], p.z[i], p.vx[i], p.vy[i], p.vz[i], hprev.empty() ? 0 : hprev[i]};
  return s;
}

struct AutoRun {
  State state;
  std::vector<double> choices;
  std::vector<std::int64_t> counts; // nsubit per interval
  std::int64_t violations = 0, pairs = 0;
};

// `intervals` control intervals as the time loop runs them.
void run_intervals(dem::IslandsScheme& isl, int intervals, AutoRun& r) {
  for (int k = 0; k < intervals; ++k) {
    const std::int64_t m = isl.begin_interval();
    r.counts.push_back(m);
    for (std::int64_t q = 0; q < m; ++q)
      isl.subiterate();
  }
}

AutoRun finish(const dem::IslandsScheme& isl, const ParticleStore& p, AutoRun r) {
  r.state = state_of(p, {});
  r.choices = isl.choices();
  r.violations = isl.bound_violations();
  r.pairs = isl.pair_evaluations();
  return r;
}

AutoRun run_auto(const Scene& s, int intervals, int threads = 1) {
  tbb::global_control gc(tbb::global_control::max_allowed_parallelism,
                         static_cast<std::size_t>(threads));
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::IslandsScheme isl(s, p, t);
  EXPECT_TRUE(isl.auto_length());
  isl.start();
  AutoRun r;
  run_intervals(isl, intervals, r);
  return finish(isl, p, std::move(r));
}

// `before` intervals, a save, a restore into a fresh scheme on the store as saved (the one-rank
// loops' path) and `after` more; `saved` gets the state.
AutoRun run_restored(const Scene& s, int before, int after, dem::IslandsScheme::State& saved) {
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  AutoRun r;
  ParticleStore at_save;
  {
    dem::IslandsScheme isl(s, p, t);
    isl.start();
    run_intervals(isl, before, r);
    saved = isl.save_state();
    at_save = p;
  }
  dem::IslandsScheme again(s, at_save, t);
  again.restore_state(saved);
  run_intervals(again, after, r);
  return finish(again, at_save, std::move(r));
}

double mean_tail(const std::vector<std::int64_t>& v, std::size_t from) {
  double s = 0.0;
  for (std::size_t k = from; k < v.size(); ++k)
    s += static_cast<double>(v[k]);
  return s / static_cast<double>(v.size() - from);
}

} // namespace

// The same gas at 1% and 8% solids: collisions come eight times as often in the denser one, so
// the count that balances the per-sub-iteration bookkeeping against the fine steps is about
// sqrt(8) = 2.8 times larger (ChoiceFindsTheModelsOptimum); the choice must follow by at least
// 1.5x, every run without a bound violation.
TEST(SubiterationLength, DenserGasTakesShorterSubiterations) {
  const AutoRun dilute = run_auto(demtest::scene_from(kAutoGas), 30);
  const AutoRun dense =
      run_auto(demtest::scene_from(kAutoGas, {"domain.hi=[1.3785e-3,1.3785e-3,1.3785e-3]"}), 30);
  EXPECT_EQ(dilute.violations, 0);
  EXPECT_EQ(dense.violations, 0);
  const double m_dilute = mean_tail(dilute.counts, 10), m_dense = mean_tail(dense.counts, 10);
  // Denser: more particles within reach per sub-iteration, so shorter ones. The link rounds'
  // cost per sub-iteration grows with the density too (kPerEntry: the rows' entries grow as
  // N^2 / V), which pulls the optimum back: 14 against 11 sub-iterations per interval (1.27x;
  // 1.5x before the model priced the rows).
  EXPECT_GT(m_dense, 1.2 * m_dilute) << "dilute " << m_dilute << ", dense " << m_dense;
  // Each choice is logged: the start row and at least one change.
  const std::size_t row = dem::IslandsScheme::kChoiceColumns.size();
  EXPECT_GE(dense.choices.size(), 2 * row);
  EXPECT_EQ(dense.choices[row - 1], length::kStart);
}

TEST(SubiterationLength, AutoBitwiseIndependentOfThreadCount) {
  const Scene s = demtest::scene_from(kAutoGas);
  const AutoRun one = run_auto(s, 12, 1), two = run_auto(s, 12, 2);
  EXPECT_EQ(one.counts, two.counts);
  EXPECT_EQ(one.choices, two.choices);
  for (const auto& [id, a] : one.state)
    EXPECT_EQ(a, two.state.at(id)) << "particle " << id;
}

// A save after some intervals and a restore into a fresh scheme (the one-rank loops' path) goes
// on bit for bit: the chosen length and its running means are state.
TEST(SubiterationLength, AutoRestoresBitwise) {
  const Scene s = demtest::scene_from(kAutoGas);
  const AutoRun whole = run_auto(s, 16);
  dem::IslandsScheme::State saved;
  const AutoRun resumed = run_restored(s, 8, 8, saved);
  EXPECT_EQ(saved.length_counters.size(), 8U);
  EXPECT_EQ(resumed.counts, whole.counts);
  EXPECT_EQ(resumed.choices, whole.choices);
  EXPECT_EQ(resumed.pairs, whole.pairs);
  for (const auto& [id, a] : whole.state)
    EXPECT_EQ(a, resumed.state.at(id)) << "particle " << id;
  // A state without the length (written with an integer nsubit) is refused.
  saved.length_counters.clear();
  ParticleStore q = make_initial_particles(s);
  PhaseTimer t;
  dem::IslandsScheme other(s, q, t);
  EXPECT_THROW(other.restore_state(saved), RunError);
}

// A dense gas (phi 0.3): nearly every particle is in an island at any length, and "auto" takes
// the global mode. Its runs stay bitwise independent of the thread count, and a state saved
// inside a global interval goes on bit for bit.
TEST(SubiterationLength, DenseGasTakesTheGlobalModeBitwise) {
  const Scene s = demtest::scene_from(kAutoGas, {"domain.hi=[0.887e-3,0.887e-3,0.887e-3]"});
  const int intervals = 6;
  const AutoRun one = run_auto(s, intervals, 1), two = run_auto(s, intervals, 2);
  const std::size_t row = dem::IslandsScheme::kChoiceColumns.size();
  bool global = false;
  for (std::size_t k = row - 1; k < one.choices.size(); k += row)
    global = global || one.choices[k] == static_cast<double>(length::kGlobal);
  EXPECT_TRUE(global);
  EXPECT_EQ(one.counts.back(), 1);
  EXPECT_EQ(one.violations, 0);
  EXPECT_EQ(one.counts, two.counts);
  EXPECT_EQ(one.choices, two.choices);
  EXPECT_EQ(one.pairs, two.pairs);
  for (const auto& [id, a] : one.state)
    EXPECT_EQ(a, two.state.at(id)) << "particle " << id;
  // Saved after the first global interval, in the middle of the run.
  dem::IslandsScheme::State saved;
  const AutoRun resumed = run_restored(s, intervals - 2, 2, saved);
  ASSERT_EQ(saved.length_counters.size(), 8U);
  EXPECT_EQ(saved.length_counters[7], 1); // the next interval is a global one
  EXPECT_EQ(resumed.counts, one.counts);
  EXPECT_EQ(resumed.pairs, one.pairs);
  for (const auto& [id, a] : one.state)
    EXPECT_EQ(a, resumed.state.at(id)) << "particle " << id;
}

// dem.nsubit = "auto" is the islands scheme's; orb refuses it, other words are refused.
TEST(SubiterationLength, SceneKey) {
  EXPECT_TRUE(demtest::scene_from(kAutoGas).dem.nsubit_auto);
  EXPECT_FALSE(demtest::scene_from(kAutoGas, {"dem.nsubit=7"}).dem.nsubit_auto);
  EXPECT_THROW(demtest::scene_from(kAutoGas, {"dem.scheme=\"orb\""}), ConfigError);
  EXPECT_THROW(demtest::scene_from(kAutoGas, {"dem.nsubit=\"fast\""}), ConfigError);
}

// Under "auto" the length changes from interval to interval while the list, the links and the
// fine steps follow it: no collision may be missed. Every pair overlapping at the end of a
// sub-iteration touched during it, so it must have been in one island (checked over all pairs,
// in a hot gas whose reaches outgrow the skin every few sub-iterations).
TEST(SubiterationLength, AutoListMissesNoContact) {
  const Scene s =
      demtest::scene_from(kAutoGas, {"particles.temperature=0.25",
                                     "domain.hi=[1.74e-3,1.74e-3,1.74e-3]", "particles.count=200"});
  ParticleStore p = make_initial_particles(s);
  PhaseTimer t;
  dem::IslandsScheme isl(s, p, t);
  isl.start();
  const DomainGeometry g(s.domain);
  std::int64_t overlapping = 0;
  for (int k = 0; k < 20; ++k) {
    const std::int64_t m = isl.begin_interval();
    for (std::int64_t q = 0; q < m; ++q) {
      isl.subiterate(true);
      const auto r = isl.synchronised_previous();
      std::unordered_map<std::int64_t, std::int64_t> island;
      for (std::size_t i = 0; i < r.id.size(); ++i)
        island[r.id[i]] = r.leaf[i];
      for (std::size_t i = 0; i < p.size(); ++i)
        for (std::size_t j = i + 1; j < p.size(); ++j) {
          const double dx = g.image(p.x[j] - p.x[i], 0), dy = g.image(p.y[j] - p.y[i], 1),
                       dz = g.image(p.z[j] - p.z[i], 2);
          if (std::sqrt(dx * dx + dy * dy + dz * dz) >= p.radius[i] + p.radius[j])
            continue;
          ++overlapping;
          const std::int64_t a = island.at(p.id[i]), b = island.at(p.id[j]);
          EXPECT_TRUE(a >= 0 && a == b) << "particles " << p.id[i] << ", " << p.id[j];
        }
    }
  }
  EXPECT_GT(overlapping, 0); // contacts happened
  EXPECT_EQ(isl.bound_violations(), 0);
  EXPECT_LT(isl.neighbor_builds(), isl.subiterations()); // the list outlived sub-iterations
}
