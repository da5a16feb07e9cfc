// Profiles along one axis of the domain (output.profile_axis, output.profile_bins): the column
// cut into equal slabs ("bins"), and per slab the solids fraction, the particles' mean velocity
// and granular temperature, and with a gas the gas volume fraction, the gas velocity, the
// pressure and the slip velocity. Users of fluidized beds and risers judge a run by such
// profiles (solids fraction against height), not by one global mean.
//
// Particles: each sphere's volume is split exactly between the slabs it crosses (the volume of
// a sphere between two planes, pi [r^2 s - s^3/3] between the planes' offsets s from its
// centre), so a bed at rest gives its true solids fraction in every slab, with no noise from
// centres near a slab's edge. A particle's share of the slab's mass weights its velocity:
//   <v>_b = sum_i w_ib v_i / sum_i w_ib,  T_b = (1/3)(sum_i w_ib |v_i|^2 / sum_i w_ib - |<v>_b|^2),
// w_ib = m_i (volume of i in b) / (volume of i): the mass-weighted granular temperature of
// docs/theory.md §3 restricted to the slab.
// Gas (the coupling's cell fields, apps/coupled_step.hpp cell_fields): cells are given to the
// slab holding their centre. eps_g and the pressure are volume
// averages; the gas velocity is the phase average sum eps u V / sum eps V (the interstitial
// velocity); the pressure is the full pressure p' + gp0 . (x - origin) (docs/theory.md §4), so an
// imposed drop shows as a slope. The slip velocity is <u_g>_b - <v_p>_b.
// A slab without particles has NaN particle columns (no mean exists), not zeros.
// On R ranks every rank sums its own particles and cells and the sums are reduced: the rows are
// those of one rank up to the order of summation.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "core/communicator.hpp"
#include "core/particle_snapshot.hpp"
#include "core/scene.hpp"
#include "fluid/gas_solver.hpp"

namespace cfddem::apps {

struct ProfileSpec {
  int axis = 1;              // 0, 1, 2 = x, y, z
  int bins = 1;              // number of equal slabs over [lo, hi]
  double lo = 0.0, hi = 1.0; // the domain's extent along the axis [m]
  double area = 1.0;         // the domain's cross-section normal to the axis [m^2]
  bool periodic = false;     // the axis is periodic: a sphere crossing hi re-enters at lo
};

// The particle columns the profiles read (the owned particles of this rank).
struct ProfileParticles {
  std::span<const double> x, y, z, vx, vy, vz, radius, mass;
};

// The profiles a scene asks for (output.profile_axis, output.profile_bins), or none.
std::optional<ProfileSpec> profile_spec(const Scene& scene);

// Fraction of a sphere's volume (centre c, radius r, along the axis) between the planes a < b.
double sphere_slab_fraction(double c, double r, double a, double b);

class ColumnProfiles {
public:
  ColumnProfiles(const ProfileSpec& spec, bool with_gas);

  // The CSV columns: time, bin, centre, then the per-bin quantities.
  [[nodiscard]] const std::vector<std::string>& columns() const { return columns_; }

  // One row per bin at time t. `gas` may be null (no gas columns then). `comm`, if given, sums
  // over its ranks (collective).
  [[nodiscard]] std::vector<std::vector<double>> rows(double t, const ProfileParticles& p,
                                                      const fluid::GasSolver* gas,
                                                      const Communicator* comm) const;
  // The same with the gas taken earlier: gas_sums() of this rank's cells at time t (a coupled
  // loop takes the gas when a row falls due and writes the row a particle step later).
  [[nodiscard]] std::vector<std::vector<double>> rows(double t, const ProfileParticles& p,
                                                      std::span<const double> gas_sums,
                                                      const Communicator* comm) const;
  [[nodiscard]] std::vector<double> gas_sums(const CellFields& cells) const;
  [[nodiscard]] bool with_gas() const { return with_gas_; }

private:
  // Per-bin sums, kParticleSums particle values then kGasSums gas values, bin-major.
  static constexpr int kParticleSums = 6; // volume, w, w vx, w vy, w vz, w |v|^2
  static constexpr int kGasSums = 6;      // V, eps V, eps V ux, eps V uy, eps V uz, p V
  void add_particles(const ProfileParticles& p, std::span<double> sums) const;
  void add_gas(const CellFields& cells, std::span<double> sums, int stride, int offset) const;
  int sums_per_bin() const { return kParticleSums + (with_gas_ ? kGasSums : 0); }

  ProfileSpec spec_;
  bool with_gas_ = false;
  std::vector<std::string> columns_;
};

} // namespace cfddem::apps
