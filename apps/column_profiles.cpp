#include "apps/column_profiles.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>

#include "apps/coupled_step.hpp"

namespace cfddem::apps {

namespace {

// Volume of the unit sphere below the plane at offset u (in radii) from its centre, as a
// fraction of the whole, shifted by one half: g(u) = 3u/4 - u^3/4, so g(1) - g(-1) = 1
// (the cap volume pi r^3 (u - u^3/3) + const over 4/3 pi r^3).
double below(double u) {
  u = std::clamp(u, -1.0, 1.0);
  return 0.75 * u - 0.25 * u * u * u;
}

} // namespace

std::optional<ProfileSpec> profile_spec(const Scene& scene) {
  const int a = scene.output.profile_axis_index();
  if (a < 0)
    return std::nullopt;
  ProfileSpec s;
  s.axis = a;
  s.bins = static_cast<int>(scene.output.profile_bins);
  s.lo = scene.domain.lo[static_cast<std::size_t>(a)];
  s.hi = scene.domain.hi[static_cast<std::size_t>(a)];
  s.area = scene.domain.length((a + 1) % 3) * scene.domain.length((a + 2) % 3);
  s.periodic = scene.domain.periodic[static_cast<std::size_t>(a)];
  return s;
}

double sphere_slab_fraction(double c, double r, double a, double b) {
  if (b <= a || r <= 0.0)
    return 0.0;
  return below((b - c) / r) - below((a - c) / r);
}

ColumnProfiles::ColumnProfiles(const ProfileSpec& spec, bool with_gas)
    : spec_(spec), with_gas_(with_gas) {
  if (spec_.axis < 0 || spec_.axis > 2 || spec_.bins < 1 || !(spec_.hi > spec_.lo) ||
      !(spec_.area > 0.0))
    throw std::invalid_argument("ColumnProfiles: bad axis, bin count, extent or area");
  columns_ = {"time", "bin",  "centre", "solids_fraction",
              "vp_x", "vp_y", "vp_z",   "granular_temperature"};
  if (with_gas_)
    for (const char* c :
         {"eps_g", "ug_x", "ug_y", "ug_z", "pressure", "slip_x", "slip_y", "slip_z"})
      columns_.emplace_back(c);
}

void ColumnProfiles::add_particles(const ProfileParticles& p, std::span<double> sums) const {
  const std::span<const double> pos = spec_.axis == 0 ? p.x : spec_.axis == 1 ? p.y : p.z;
  const int nb = spec_.bins, stride = sums_per_bin();
  const double h = (spec_.hi - spec_.lo) / nb;
  for (std::size_t i = 0; i < pos.size(); ++i) {
    const double c = pos[i], r = p.radius[i];
    const double volume = 4.0 / 3.0 * std::numbers::pi * r * r * r;
    const double v2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
    // Slabs the sphere can reach, counted on the unwrapped axis (a periodic image re-enters).
    const auto b0 = static_cast<long>(std::floor((c - r - spec_.lo) / h));
    const auto b1 = static_cast<long>(std::floor((c + r - spec_.lo) / h));
    for (long b = b0; b <= b1; ++b) {
      long bin = b;
      if (spec_.periodic)
        bin = ((b % nb) + nb) % nb;
      else if (b < 0 || b >= nb)
        continue; // the part of a sphere pressed into a wall lies outside the column
      const double a = spec_.lo + static_cast<double>(b) * h;
      const double f = sphere_slab_fraction(c, r, a, a + h);
      if (f <= 0.0)
        continue;
      const double w = p.mass[i] * f;
      double* s = sums.data() + bin * stride;
      s[0] += volume * f;
      s[1] += w;
      s[2] += w * p.vx[i];
      s[3] += w * p.vy[i];
      s[4] += w * p.vz[i];
      s[5] += w * v2;
    }
  }
}

void ColumnProfiles::add_gas(const CellFields& c, std::span<double> sums, int stride,
                             int offset) const {
  // This rank's block of cells (the whole grid when block_cells is zero), cell (i, j, k) at
  // global index block_lo + (i, j, k); arrays in (k, j, i) order, velocity 3 per cell.
  std::array<std::int64_t, 3> n = c.block_cells;
  if (n[0] == 0 && n[1] == 0 && n[2] == 0)
    n = c.cells;
  const std::vector<double>* nodes[3] = {&c.x_nodes, &c.y_nodes, &c.z_nodes};
  const auto a = static_cast<std::size_t>(spec_.axis);
  double dv = 1.0;
  for (std::size_t q = 0; q < 3; ++q)
    dv *= (*nodes[q])[1] - (*nodes[q])[0];
  const int nb = spec_.bins;
  const double h = (spec_.hi - spec_.lo) / nb;
  std::size_t cell = 0;
  for (std::int64_t k = 0; k < n[2]; ++k)
    for (std::int64_t j = 0; j < n[1]; ++j)
      for (std::int64_t i = 0; i < n[0]; ++i, ++cell) {
        const std::int64_t idx[3] = {i, j, k};
        const auto g = static_cast<std::size_t>(c.block_lo[a] + idx[a]);
        const double centre = 0.5 * ((*nodes[a])[g] + (*nodes[a])[g + 1]);
        const auto bin = std::clamp(static_cast<long>(std::floor((centre - spec_.lo) / h)), 0L,
                                    static_cast<long>(nb - 1));
        const double e = c.eps_g[cell] * dv;
        double* s = sums.data() + bin * stride + offset;
        s[0] += dv;
        s[1] += e;
        s[2] += e * c.gas_velocity[3 * cell];
        s[3] += e * c.gas_velocity[3 * cell + 1];
        s[4] += e * c.gas_velocity[3 * cell + 2];
        s[5] += c.pressure[cell] * dv;
      }
}

std::vector<double> ColumnProfiles::gas_sums(const CellFields& cells) const {
  std::vector<double> sums(static_cast<std::size_t>(spec_.bins * kGasSums), 0.0);
  add_gas(cells, sums, kGasSums, 0);
  return sums;
}

std::vector<std::vector<double>> ColumnProfiles::rows(double t, const ProfileParticles& p,
                                                      const fluid::GasSolver* gas,
                                                      const Communicator* comm) const {
  if (with_gas_ && gas == nullptr)
    throw std::logic_error("ColumnProfiles: gas columns without a gas");
  return rows(t, p, with_gas_ ? gas_sums(cell_fields(*gas)) : std::vector<double>{}, comm);
}

std::vector<std::vector<double>> ColumnProfiles::rows(double t, const ProfileParticles& p,
                                                      std::span<const double> gas,
                                                      const Communicator* comm) const {
  const int nb = spec_.bins, stride = sums_per_bin();
  if (with_gas_ && gas.size() != static_cast<std::size_t>(nb * kGasSums))
    throw std::logic_error("ColumnProfiles: gas sums of the wrong size");
  std::vector<double> sums(static_cast<std::size_t>(nb * stride), 0.0);
  add_particles(p, sums);
  if (with_gas_)
    for (int b = 0; b < nb; ++b)
      for (int q = 0; q < kGasSums; ++q)
        sums[static_cast<std::size_t>(b * stride + kParticleSums + q)] =
            gas[static_cast<std::size_t>(b * kGasSums + q)];
  if (comm != nullptr)
    comm->sum(std::span<double>(sums));

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double h = (spec_.hi - spec_.lo) / nb;
  std::vector<std::vector<double>> out;
  out.reserve(static_cast<std::size_t>(nb));
  for (int b = 0; b < nb; ++b) {
    const double* s = sums.data() + b * stride;
    std::vector<double> row{t, static_cast<double>(b), spec_.lo + (b + 0.5) * h,
                            s[0] / (spec_.area * h)};
    std::array<double, 3> vp{nan, nan, nan};
    double temperature = nan;
    if (s[1] > 0.0) {
      vp = {s[2] / s[1], s[3] / s[1], s[4] / s[1]};
      const double mean2 = vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2];
      // Round-off can leave a tiny negative value for a slab of particles at one velocity.
      temperature = std::max(0.0, (s[5] / s[1] - mean2) / 3.0);
    }
    row.insert(row.end(), {vp[0], vp[1], vp[2], temperature});
    if (with_gas_) {
      const double* q = s + kParticleSums;
      std::array<double, 3> ug{nan, nan, nan};
      if (q[1] > 0.0)
        ug = {q[2] / q[1], q[3] / q[1], q[4] / q[1]};
      const double eps_g = q[0] > 0.0 ? q[1] / q[0] : nan;
      const double pressure = q[0] > 0.0 ? q[5] / q[0] : nan;
      row.insert(row.end(), {eps_g, ug[0], ug[1], ug[2], pressure, ug[0] - vp[0], ug[1] - vp[1],
                             ug[2] - vp[2]});
    }
    out.push_back(std::move(row));
  }
  return out;
}

} // namespace cfddem::apps
