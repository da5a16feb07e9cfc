#include "apps/census_columns.hpp"

#include <chrono>

#include <fmt/format.h>

namespace cfddem::apps {

const std::vector<std::string>& census_columns() {
  static const std::vector<std::string> columns = [] {
    std::vector<std::string> c = {
        "contacts",          "wall_contacts",    "overlap_mean",        "overlap_max",
        "wall_overlap_mean", "wall_overlap_max", "collision_frequency", "wall_collision_frequency"};
    for (int b = 0; b < dem::kCoordinationBins; ++b)
      c.push_back(fmt::format("coordination_{}", b));
    return c;
  }();
  return columns;
}

CensusColumns::CensusColumns(const Scene& scene)
    : enabled_(scene.output.contact_census),
      geometry_(scene.domain), laws_{scene.dem.spring_constant, scene.dem.restitution,
                                     scene.dem.wall_spring_constant, scene.dem.wall_restitution} {}

namespace {

std::vector<double> values(const dem::ContactCensus& c) {
  std::vector<double> v = {static_cast<double>(c.pair_contacts),
                           static_cast<double>(c.wall_contacts),
                           c.pair_overlap_mean,
                           c.pair_overlap_max,
                           c.wall_overlap_mean,
                           c.wall_overlap_max,
                           c.collision_frequency,
                           c.wall_collision_frequency};
  for (const std::int64_t n : c.coordination)
    v.push_back(static_cast<double>(n));
  return v;
}

} // namespace

std::vector<double> CensusColumns::row(const Communicator& comm, const dem::CensusParticles& mine) {
  if (!enabled_)
    return {}; // no census columns in the file
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<double> row;
  if (comm.size() == 1) {
    row = values(dem::take_census(mine, geometry_, laws_, work_));
  } else {
    // Five numbers a particle.
    constexpr std::size_t kFields = 5;
    std::vector<double> packed(kFields * mine.x.size());
    for (std::size_t i = 0; i < mine.x.size(); ++i) {
      double* q = &packed[kFields * i];
      q[0] = mine.x[i], q[1] = mine.y[i], q[2] = mine.z[i], q[3] = mine.radius[i];
      q[4] = mine.mass[i];
    }
    const std::vector<double> all = comm.gather(std::span<const double>(packed));
    row.assign(census_columns().size(), 0.0);
    if (comm.rank() == 0) {
      const std::size_t n = all.size() / kFields;
      std::vector<double> col[kFields];
      for (std::size_t f = 0; f < kFields; ++f) {
        col[f].resize(n);
        for (std::size_t i = 0; i < n; ++i)
          col[f][i] = all[kFields * i + f];
      }
      row = values(
          dem::take_census({col[0], col[1], col[2], col[3], col[4]}, geometry_, laws_, work_));
    }
    comm.sum(row); // the other ranks add zeros: every rank gets rank 0's values exactly
  }
  seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return row;
}

} // namespace cfddem::apps
