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

// First-contact times spread evenly, B(dt) = N dt / T (capped at N). An island folds the steps
// before and after its contacts, so its members cost kFreeSteps steps each besides the contact
// steps, and an interval's members' work m B(D / m) kFreeSteps = N D / T kFreeSteps is the same
// at every m: the least cost is the fewest sub-iterations, down to where the members pass half
// the global switch (kSwitchMargin kGlobalFraction of the particles; every particle on the fine
// steps there): m* = ceil(D / (T f)), f = kSwitchMargin kGlobalFraction, the skin's bound when
// that is higher, and 1 when nothing comes near.
TEST(SubiterationLength, ChoiceTakesTheFewestSubiterationsBelowTheGlobalSwitch) {
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
  const length::Rho one{};
  const double f = length::kSwitchMargin * length::kGlobalFraction;
  for (const double T : {1e-3, 1.3e-4, 0.9e-5}) { // m* = 1, 7, 89
    const auto m_star =
        static_cast<std::int64_t>(std::max(1.0, std::ceil(D / (T * f) * (1.0 - 1e-12))));
    const length::Choice c =
        length::choose(spread(T), N, D, dt_f, one, 1, m_hi, m_hi, length::kSkin);
    EXPECT_EQ(c.m, m_star) << "T = " << T;
    EXPECT_EQ(c.reason, length::kMinCost);
    EXPECT_FALSE(c.global);
    // The skin's bound above it sets the count.
    const length::Choice skin =
        length::choose(spread(T), N, D, dt_f, one, m_star + 2, m_hi, 1, length::kSkin);
    EXPECT_EQ(skin.m, m_star + 2);
    EXPECT_EQ(skin.reason, length::kSkin);
  }
  std::vector<double> none(static_cast<std::size_t>(m_hi) + 1, 0.0);
  EXPECT_EQ(length::choose(none, N, D, dt_f, one, 3, m_hi, 10, length::kSkin).m, 3);
  EXPECT_EQ(length::choose(none, N, D, dt_f, one, 1, m_hi, 10, length::kSkin).m, 1);
  // Next to the optimum the previous count is kept (the best saves less than kMinGain); far
  // from it the count changes. T = 1.1e-4: m* = 8; per interval the members' work is kFreeSteps
  // kPerFineStep N D / T against kPerParticle N per sub-iteration.
  const double T = 1.1e-4, work = length::kFreeSteps * length::kPerFineStep * N * D / T;
  auto C = [&](double m) { return m * length::kPerParticle * N + work; };
  ASSERT_GT(C(8) / C(9), 1.0 - length::kMinGain);
  const length::Choice kept = length::choose(spread(T), N, D, dt_f, one, 1, m_hi, 9, 0);
  EXPECT_EQ(kept.m, 9);
  EXPECT_EQ(kept.reason, length::kKept);
  const length::Choice moved = length::choose(spread(T), N, D, dt_f, one, 1, m_hi, 14, 0);
  EXPECT_EQ(moved.m, 8);
  EXPECT_NEAR(moved.cost_ratio, C(8) / C(14), 1e-9);
  // rho scales the members: 4x the members pass the switch at 4x the count (29.1: 30).
  const length::Choice more = length::choose(spread(T), N, D, dt_f, {4.0, 1.0}, 1, m_hi, 1, 0);
  EXPECT_EQ(more.m, 30);
}

// The members measured over the last interval bound the estimate from below where the
// first-contact count sees nobody (a settling bed: particles apart at the interval's end, linked
// through their raised bounds during it): 30% of the particles at m = 1 put m = 1 past the
// switch, and m holds at least 0.3 N / m, below the margin's eighth from m = 3 on.
TEST(SubiterationLength, MeasuredMembersHoldTheLengthBack) {
  const double D = 1e-4, dt_f = 1e-7, N = 1e4;
  const std::int64_t m_hi = length::most_subiterations(D, dt_f);
  std::vector<double> none(static_cast<std::size_t>(m_hi) + 1, 0.0);
  const length::Choice blind = length::choose(none, N, D, dt_f, {}, 1, m_hi, 5, length::kSkin);
  EXPECT_EQ(blind.m, 1);
  length::Rho rho;
  rho.measured = 0.3 * N, rho.at = 1;
  const length::Choice held = length::choose(none, N, D, dt_f, rho, 1, m_hi, 5, length::kSkin);
  EXPECT_EQ(held.m, 3);
  EXPECT_NEAR(held.busy_estimate, 0.1 * N, 1e-9 * N);
  // Below the margin the measured count only scales: 10% at m = 1 allows m = 1.
  rho.measured = 0.1 * N;
  EXPECT_EQ(length::choose(none, N, D, dt_f, rho, 1, m_hi, 5, length::kSkin).m, 1);
}

// The rows' entries price each sub-iteration too. 12% of the particles turn members for m < 2
// (first-contact time between D / 2 and D): one sub-iteration costs the overhead O plus their
// kFreeSteps steps, 840 x 0.12 N = 100.8 N, two cost 2 O. Without entries (O = 90 N) the second
// sub-iteration pays; with entries that make O four times as dear it does not.
// row_entries is N^2 / V (4/3) pi (2 r + s)^3.
TEST(SubiterationLength, RowEntriesPriceEachSubiteration) {
  const double D = 1e-4, dt_f = 1e-7, N = 1e5;
  const std::int64_t m_hi = length::most_subiterations(D, dt_f);
  std::vector<double> h(static_cast<std::size_t>(m_hi) + 1, 0.0);
  h[1] = 0.12 * N;
  const double entries = 3.0 * length::kPerParticle * N / length::kPerEntry;
  ASSERT_LT(0.12, length::kSwitchMargin * length::kGlobalFraction);
  const length::Choice plain = length::choose(h, N, D, dt_f, {}, 1, m_hi, 3, 0);
  const length::Choice priced = length::choose(h, N, D, dt_f, {}, 1, m_hi, 3, 0, entries);
  EXPECT_EQ(plain.m, 2);
  EXPECT_NEAR(plain.cost_ratio, 2.0 / 3.0, 1e-9);
  EXPECT_EQ(priced.m, 1);
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
      length::choose(dense, N, D, dt_f, {}, 1, m_hi, 1, length::kSkin, entries);
  EXPECT_FALSE(isl.global);
  const length::Choice g =
      length::choose(dense, N, D, dt_f, {}, 1, m_hi, 1, length::kSkin, entries, pairs);
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
      length::choose(dense, N, D, dt_f, {}, 1, m_hi, 1, length::kSkin, entries, pairs, true);
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
      length::choose(spread, Nd, D, dt_f, {}, 1, m_hi, 1, length::kSkin, 0.0, 0.078, true);
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

// The same gas at 1% and 8% solids. In the dilute one the members' work per interval is the
// same at every length (ChoiceTakesTheFewestSubiterationsBelowTheGlobalSwitch), so the choice
// is the fewest sub-iterations the skin allows (2 here); in the denser one eight times as many
// particles come within reach, and the longest sub-iteration whose members stay below half the
// global switch is shorter (6-7 here). The choice must follow by at least 2x, every run without
// a bound violation.
TEST(SubiterationLength, DenserGasTakesShorterSubiterations) {
  const AutoRun dilute = run_auto(demtest::scene_from(kAutoGas), 30);
  const AutoRun dense =
      run_auto(demtest::scene_from(kAutoGas, {"domain.hi=[1.3785e-3,1.3785e-3,1.3785e-3]"}), 30);
  EXPECT_EQ(dilute.violations, 0);
  EXPECT_EQ(dense.violations, 0);
  const double m_dilute = mean_tail(dilute.counts, 10), m_dense = mean_tail(dense.counts, 10);
  // Denser: more particles within reach per sub-iteration, so shorter ones.
  EXPECT_GT(m_dense, 2.0 * m_dilute) << "dilute " << m_dilute << ", dense " << m_dense;
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
