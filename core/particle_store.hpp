// Particle data as structure of arrays: one contiguous array per field, so kernels stream and
// vectorize. Rotation fields exist only when the scene has friction ("model only what is needed").
#pragma once

#include <cstddef>
#include <cstdint>
#include <numbers>
#include <span>
#include <vector>

namespace cfddem {

struct ParticleStore {
  std::vector<double> x, y, z;    // position [m]
  std::vector<double> vx, vy, vz; // velocity [m/s] (half-step velocity inside the integrator)
  std::vector<double> fx, fy, fz; // contact + wall force of the last evaluation [N]
  std::vector<double> radius;     // [m]
  std::vector<double> mass;       // [kg]
  std::vector<double> inv_mass;   // 1/mass, kept so the update multiplies
  std::vector<std::int64_t> id;   // stable identity across reordering and ranks

  bool rotation = false;           // angular fields present (friction on)
  std::vector<double> wx, wy, wz;  // angular velocity [rad/s]
  std::vector<double> tx, ty, tz;  // torque [N m]
  std::vector<double> inv_inertia; // 1/I, I = m d^2 / 10 for a solid sphere

  std::size_t size() const { return x.size(); }
  void enable_rotation();
  void resize(std::size_t n);
  // Append one particle at rest with zero force; returns its index.
  // Mass of a sphere of radius r [m] and density [kg/m^3], as add() stores it.
  static double sphere_mass(double density, double r) {
    return density * (4.0 / 3.0) * std::numbers::pi * r * r * r;
  }
  std::size_t add(double px, double py, double pz, double pvx, double pvy, double pvz, double r,
                  double density, std::int64_t pid);
  // Particle i's mass [kg], exactly (a particle that re-enters keeps the mass it left with), and
  // what follows from it: 1/m and the inverse moment of inertia.
  void set_mass(std::size_t i, double m);
  // Reorder every field so that new index k holds old index order[k].
  void permute(std::span<const std::uint32_t> order);
  // Exchange particles a and b in every field (a few particles changing place: cheaper than a
  // permutation of the whole store).
  void swap(std::size_t a, std::size_t b);
  double total_mass() const;

private:
  std::vector<double> scratch_; // permute() reuses these: no allocation per neighbor build
  std::vector<std::int64_t> scratch_id_;
};

} // namespace cfddem
