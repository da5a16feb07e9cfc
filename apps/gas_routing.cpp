#include "apps/gas_routing.hpp"

#include <algorithm>
#include <bit>
#include <numeric>

#include <fmt/format.h>

#include "core/error.hpp"
#include "core/sparse_exchange.hpp"
#include "core/stopwatch.hpp"

namespace cfddem::apps {

namespace {

constexpr int kOut = 9;  // x, y, z, vx, vy, vz, radius, id, mass
constexpr int kBack = 4; // fx, fy, fz, id

} // namespace

GasRouting::GasRouting(const Communicator& comm, partition::RankDecomposition boxes,
                       const dem::DomainGeometry& geom)
    : comm_(comm), boxes_(std::move(boxes)), geom_(geom) {}

const ParticleStore& GasRouting::route(const ParticleStore& p, std::size_t owned) {
  Stopwatch sw(seconds_);
  const int ranks = comm_.size(), me = comm_.rank();
  // Destination of each owned particle, then a counting sort by rank (each rank's copies in
  // store order).
  std::vector<int> dest(owned);
  std::vector<std::array<double, 3>> wrapped(owned);
  send_counts_.assign(static_cast<std::size_t>(ranks), 0);
  for (std::size_t i = 0; i < owned; ++i) {
    auto& w = wrapped[i];
    w = {geom_.wrap(p.x[i], 0), geom_.wrap(p.y[i], 1), geom_.wrap(p.z[i], 2)};
    const int r = boxes_.owner_of(w[0], w[1], w[2]);
    if (r < 0)
      throw RunError(fmt::format("gas routing: particle id {} at ({}, {}, {}) is outside the "
                                 "domain",
                                 p.id[i], w[0], w[1], w[2]));
    dest[i] = r;
    ++send_counts_[static_cast<std::size_t>(r)];
  }
  std::vector<std::size_t> at(static_cast<std::size_t>(ranks) + 1, 0);
  for (int r = 0; r < ranks; ++r)
    at[r + 1] = at[r] + static_cast<std::size_t>(send_counts_[r]);
  sent_away_ = owned - static_cast<std::size_t>(send_counts_[static_cast<std::size_t>(me)]);
  slot_.resize(owned);
  sent_id_.resize(owned);
  send_.resize(owned * kOut);
  for (std::size_t i = 0; i < owned; ++i) {
    const std::size_t s = at[static_cast<std::size_t>(dest[i])]++;
    slot_[i] = static_cast<std::uint32_t>(s);
    sent_id_[s] = p.id[i];
    double* o = send_.data() + s * kOut;
    o[0] = wrapped[i][0], o[1] = wrapped[i][1], o[2] = wrapped[i][2];
    o[3] = p.vx[i], o[4] = p.vy[i], o[5] = p.vz[i], o[6] = p.radius[i];
    o[7] = std::bit_cast<double>(p.id[i]);
    o[8] = p.mass[i];
  }
  sparse_exchange(comm_, send_counts_, send_, recv_counts_, recv_, kOut, false);
  // The box store in id order: the deposit order then depends on the particles only, not on
  // which rank owned them in what order (a restart, whose owners differ, deposits alike).
  const std::size_t n = recv_.size() / kOut;
  arrival_.resize(n);
  std::iota(arrival_.begin(), arrival_.end(), 0U);
  auto id_at = [&](std::uint32_t q) { return std::bit_cast<std::int64_t>(recv_[q * kOut + 7]); };
  std::sort(arrival_.begin(), arrival_.end(),
            [&](std::uint32_t a, std::uint32_t b) { return id_at(a) < id_at(b); });
  box_.resize(n);
  for (std::size_t k = 0; k < n; ++k) {
    const double* in = recv_.data() + static_cast<std::size_t>(arrival_[k]) * kOut;
    box_.x[k] = in[0], box_.y[k] = in[1], box_.z[k] = in[2];
    box_.vx[k] = in[3], box_.vy[k] = in[4], box_.vz[k] = in[5], box_.radius[k] = in[6];
    box_.id[k] = std::bit_cast<std::int64_t>(in[7]);
    box_.set_mass(k, in[8]); // with 1/m: the adaptive fluid step's drag time reads it
  }
  return box_;
}

void GasRouting::return_force(const std::array<std::span<const double>, 3>& f) {
  Stopwatch sw(seconds_);
  const std::size_t n = box_.size();
  for (const auto& v : f)
    if (v.size() != n)
      throw RunError(fmt::format("gas routing: {} forces for {} routed particles", v.size(), n));
  // Back along the same pairs of ranks: what arrived from rank r returns to it in its order.
  send_.resize(n * kBack);
  for (std::size_t k = 0; k < n; ++k) {
    double* o = send_.data() + static_cast<std::size_t>(arrival_[k]) * kBack;
    o[0] = f[0][k], o[1] = f[1][k], o[2] = f[2][k];
    o[3] = std::bit_cast<double>(box_.id[k]);
  }
  std::vector<std::int64_t> back = send_counts_;
  sparse_exchange(comm_, recv_counts_, send_, back, recv_, kBack, true);
  const std::size_t owned = slot_.size();
  for (auto& v : force_)
    v.resize(owned);
  for (std::size_t i = 0; i < owned; ++i) {
    const double* in = recv_.data() + static_cast<std::size_t>(slot_[i]) * kBack;
    if (std::bit_cast<std::int64_t>(in[3]) != sent_id_[slot_[i]])
      throw RunError(fmt::format("gas routing: the force for particle id {} came back as id {}",
                                 sent_id_[slot_[i]], std::bit_cast<std::int64_t>(in[3])));
    force_[0][i] = in[0], force_[1][i] = in[1], force_[2][i] = in[2];
  }
}

} // namespace cfddem::apps
