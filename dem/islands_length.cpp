// The islands scheme's dem.nsubit = "auto" (dem/subiteration_length.hpp): the control interval,
// the choice at its end from counts summed over ranks, and the gas force's change bound.
#include <algorithm>
#include <cmath>

#include "dem/islands_rank_part.hpp"
#include "dem/islands_scheme.hpp"
#include "dem/subiteration_length.hpp"

namespace cfddem::dem {

namespace {
constexpr std::size_t kRow = IslandsScheme::kChoiceColumns.size();
} // namespace

std::int64_t IslandsScheme::begin_interval() {
  if (!auto_.on)
    return nsubit_;
  const double D = auto_.interval;
  const std::int64_t m_hi = length::most_subiterations(D, model_.dt);
  if (auto_.log.empty())
    auto_.log = {0.0,
                 static_cast<double>(auto_.next),
                 D / static_cast<double>(auto_.next),
                 0.0,
                 1.0,
                 static_cast<double>(m_hi),
                 0.0,
                 1.0,
                 1.0,
                 length::kStart};
  // An adaptive fluid.dt: this interval A differs from the reference D the choice was made for.
  // The choice is a sub-iteration length, D / next, kept over A; the gas force changed over the
  // previous interval and changes at that rate over this one.
  const bool variable = auto_.variable;
  const double A = variable ? auto_.actual : D;
  const std::int64_t a_hi = variable ? length::most_subiterations(A, model_.dt) : m_hi;
  std::int64_t m =
      variable ? length::subiterations_over(A, D / static_cast<double>(auto_.next), model_.dt)
               : auto_.next;
  const double dA =
      variable && auto_.previous > 0.0 ? auto_.gas_dA * (A / auto_.previous) : auto_.gas_dA;
  const double t_now = variable ? time() : static_cast<double>(auto_.intervals) * D;
  // With a gas the force just computed for this fluid step: its change since the last one
  // bounds the length now (the choice at the last interval's end saw the change before).
  // The global mode holds the gas force over the whole interval, as the explicit scheme holds it
  // over the fluid step: the change bound is the islands' (their free flights).
  if (dA > 0.0 && !auto_.next_global) {
    const std::int64_t lo = std::min(a_hi, length::fewest_for_gas(dA, auto_.gas_aref));
    if (lo > m) {
      m = lo;
      auto_.log.insert(auto_.log.end(), {t_now, static_cast<double>(m), A / static_cast<double>(m),
                                         0.0, static_cast<double>(lo), static_cast<double>(a_hi),
                                         0.0, 1.0, 1.0, length::kGas});
    }
    if (auto_.gas_aref > 0.0)
      auto_.gas_ratio_max =
          std::max(auto_.gas_ratio_max, dA / (static_cast<double>(m) * auto_.gas_aref));
  }
  auto_.log[auto_.log.size() - kRow + 3] += 1.0; // the row in force counts this interval
  open_interval(m);
  ++auto_.intervals;
  return nsubit_;
}

void IslandsScheme::begin_completion() {
  if (auto_.on)
    open_interval(
        length::most_subiterations(auto_.variable ? auto_.actual : auto_.interval, model_.dt));
}

void IslandsScheme::set_interval(double interval) {
  IntervalClock::check_interval(interval, "islands");
  if (!auto_.on) {
    clock_.set_length(st_.subits, dt_sp_, interval / static_cast<double>(nsubit_));
    return;
  }
  if (!auto_.variable && auto_.intervals == 0) {
    // The first fluid step is the reference of the choices (their first-contact histogram counts
    // sub-iterations of it): the start's count at most its fine steps.
    auto_.interval = interval;
    auto_.next =
        std::min<std::int64_t>(scene_.dem.nsubit, length::most_subiterations(interval, model_.dt));
  }
  auto_.previous = auto_.variable ? auto_.actual : interval;
  auto_.actual = interval;
  auto_.variable = true;
}

// The next sub-iterations are m of A / m (A: the interval, with an adaptive fluid.dt the one in
// force) from the end of the intervals begun so far, in the mode the last choice took.
void IslandsScheme::open_interval(std::int64_t m) {
  const double D = auto_.interval;
  auto_.global_now = auto_.next_global;
  if (auto_.variable) {
    auto_.t0 = time(); // the end of the last interval (before dt_sp and the base change)
    dt_sp_ = auto_.actual / static_cast<double>(m);
  } else {
    dt_sp_ = D / static_cast<double>(m);
    auto_.t0 = static_cast<double>(auto_.intervals) * D;
  }
  nsubit_ = m;
  auto_.subits_base = st_.subits;
  auto_.q = 0;
}

// At the end of an interval: the next interval's m (dem/subiteration_length.hpp), from this
// sub-iteration's rows and bounds and the fine fractions measured since the last choice.
void IslandsScheme::choose_length() {
  const double D = auto_.interval;
  const std::int64_t m_hi = length::most_subiterations(D, model_.dt);
  // The length in force as sub-iterations of D (an adaptive fluid.dt takes it over another
  // interval, in another count).
  const std::int64_t m_now =
      auto_.variable
          ? std::clamp<std::int64_t>(std::llround(D / dt_sp_), 1, std::max<std::int64_t>(1, m_hi))
          : nsubit_;
  std::vector<std::int64_t> hist(static_cast<std::size_t>(m_hi) + 1, 0);
  // No running means yet: the first choice (or a histogram of another length).
  const bool first = auto_.fine_avg < 0.0 || auto_.hist_avg.size() != hist.size();
  // The histogram once about kCountSpacing sub-iterations have passed (and at the first choice);
  // the same on every rank.
  const bool count = first || length::counts_after(auto_.intervals, m_now, auto_.global_now);
  double s_max = 0.0;
  if (auto_.global_now && !rank_)
    speed_bounds(); // the global mode's sub-iterations make none
  // The skin's bound from every particle's own speed bound: a member's raised one differs
  // between rank counts (an island spanning ranks is raised to one bound for all spanning
  // islands), and the fewest sub-iterations the skin allows is where a dilute gas's choice lies.
  // The histogram takes the bounds the links take (raised: in a settling bed they link 4-16x the
  // particles own bounds would).
  // (In the global mode no link round ran: ln_.bound holds the own bounds just made, and the
  // saved ones are stale.)
  const bool bounds = ln_.bound.size() >= p_.size();
  const bool saved = !auto_.global_now;
  if (bounds)
    for (std::size_t i = 0; i < owned_; ++i)
      s_max = std::max(s_max, saved && i < ln_.own_stamp.size() && ln_.own_stamp[i] == ln_.stamp
                                  ? ln_.own_bound[i]
                                  : ln_.bound[i]);
  if (count) {
    length::RowsView v{{},      {},    p_.x.data(), p_.y.data(), p_.z.data(), p_.radius.data(),
                       nullptr, owned_};
    if (rank_) {
      // The ghosts at their owners' positions now, as one rank sees them (one message round; the
      // next sub-iteration forwards them again).
      std::vector<double>* cols[] = {&p_.x, &p_.y, &p_.z};
      rank_->exchange.forward_columns(cols);
      v.x = p_.x.data(), v.y = p_.y.data(), v.z = p_.z.data();
      v.offsets = rank_->rows.off(), v.neighbors = rank_->rows.nb();
    } else if (one_.built)
      v.offsets = one_.list.offsets(), v.neighbors = one_.list.neighbors();
    v.bound = ln_.bound.data();
    if (bounds && v.offsets.size() == owned_ + 1)
      length::first_contact_histogram(v, geom_, margin_, D, m_hi, hist);
    if (rank_)
      rank_->comm.sum(std::span<std::int64_t>(hist));
  }
  if (rank_)
    s_max = rank_->comm.max(s_max);
  const double N = static_cast<double>(n_global_);
  double busy_now = 0.0;
  for (std::int64_t c = std::min(m_now, m_hi); c <= m_hi; ++c)
    busy_now += count ? static_cast<double>(hist[static_cast<std::size_t>(c)])
                      : auto_.hist_avg[static_cast<std::size_t>(c)];
  const bool measured = auto_.fine_count > 0;
  const auto per_subit = [&](double sum) {
    return measured ? sum / static_cast<double>(auto_.fine_count) * N : busy_now;
  };
  const double fine_now = per_subit(auto_.fine_sum), members_now = per_subit(auto_.members_sum);
  // Running means that follow a rise at once (a bed settling into contact within a few
  // intervals) and a fall over about 1 / kSmoothing choices.
  const double w = length::kSmoothing;
  auto follow = [&](double& avg, double now) { avg = std::max(now, avg + w * (now - avg)); };
  if (first) {
    auto_.hist_avg.assign(hist.begin(), hist.end());
    auto_.fine_avg = fine_now, auto_.busy_avg = busy_now, auto_.members_avg = members_now;
  } else {
    if (count)
      for (std::size_t c = 0; c < hist.size(); ++c)
        auto_.hist_avg[c] += w * (static_cast<double>(hist[c]) - auto_.hist_avg[c]);
    follow(auto_.fine_avg, fine_now);
    follow(auto_.busy_avg, busy_now);
    follow(auto_.members_avg, members_now);
  }
  const auto ratio = [&](double q) {
    return std::clamp((q + 1.0) / (auto_.busy_avg + 1.0), 1.0 / 64.0, 64.0);
  };
  const length::Rho rho{ratio(auto_.members_avg), ratio(auto_.fine_avg),
                        measured ? members_now : 0.0, measured ? m_now : 0};
  // The starting islands skin, not the one chosen since on one rank (choose_skin): R ranks keep
  // theirs, and every rank count must take the same length. A chosen skin shorter than a length
  // needs grows at its first expiry.
  const std::int64_t lo_skin = length::fewest_for_skin(D, s_max, one_.nominal_skin);
  const std::int64_t lo_gas = length::fewest_for_gas(auto_.gas_dA, auto_.gas_aref);
  const double volume = geom_.length[0] * geom_.length[1] * geom_.length[2];
  const double entries = length::row_entries(N, volume, model_.r_min, one_.nominal_skin);
  // The global mode's list holds the explicit scheme's pairs (its skin).
  const double pairs =
      N > 0.0 ? 0.5 * length::row_entries(N, volume, model_.r_min, model_.skin) / N : 0.0;
  const length::Choice c = length::choose(
      auto_.hist_avg, N, D, model_.dt, rho, std::max(lo_skin, lo_gas), m_hi, m_now,
      lo_gas > lo_skin ? length::kGas : length::kSkin, entries, pairs, auto_.global_now);
  auto_.next = c.m;
  auto_.next_global = c.global;
  auto_.fine_sum = 0.0, auto_.members_sum = 0.0, auto_.fine_count = 0;
  const std::size_t last = auto_.log.size() - kRow;
  if (auto_.log[last + 1] != static_cast<double>(c.m) || c.global != auto_.global_now)
    auto_.log.insert(auto_.log.end(),
                     {time(), static_cast<double>(c.m), D / static_cast<double>(c.m), 0.0,
                      static_cast<double>(c.m_lo), static_cast<double>(c.m_hi), c.busy_estimate,
                      c.rho, c.cost_ratio, static_cast<double>(c.reason)});
}

// Collective on R ranks. The largest change of a held acceleration from the force held so far to
// `f`, and the largest held acceleration of `f` (or |g|): the gas bound of the next intervals.
void IslandsScheme::note_gas_change(std::span<const double> fx, std::span<const double> fy,
                                    std::span<const double> fz) {
  double m[2] = {0.0, std::sqrt(model_.gravity[0] * model_.gravity[0] +
                                model_.gravity[1] * model_.gravity[1] +
                                model_.gravity[2] * model_.gravity[2])};
  if (ext_.active() && fx.size() == owned_ && ext_.x.size() >= owned_ && fy.size() == owned_ &&
      fz.size() == owned_)
    for (std::size_t i = 0; i < owned_; ++i) {
      const double ex = fx[i] - ext_.x[i], ey = fy[i] - ext_.y[i], ez = fz[i] - ext_.z[i];
      m[0] = std::max(m[0], std::sqrt(ex * ex + ey * ey + ez * ez) * p_.inv_mass[i]);
      m[1] =
          std::max(m[1], std::sqrt(fx[i] * fx[i] + fy[i] * fy[i] + fz[i] * fz[i]) * p_.inv_mass[i]);
    }
  if (rank_)
    rank_->comm.max(std::span<double>(m));
  auto_.gas_dA = m[0], auto_.gas_aref = m[1];
}

} // namespace cfddem::dem
