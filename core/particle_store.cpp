#include "core/particle_store.hpp"

#include <utility>

#include <numbers>

namespace cfddem {

namespace {
// Gather into `scratch`, then swap: the old array becomes the scratch of the next field, so a
// whole permutation allocates nothing once the store has been permuted before.
template <class T>
void permute_field(std::vector<T>& v, std::span<const std::uint32_t> order, std::vector<T>& scratch) {
  scratch.resize(order.size());
  for (std::size_t k = 0; k < order.size(); ++k) scratch[k] = v[order[k]];
  v.swap(scratch);
}
} // namespace

void ParticleStore::enable_rotation() {
  if (rotation) return;
  rotation = true;
  const std::size_t n = size();
  wx.assign(n, 0.0), wy.assign(n, 0.0), wz.assign(n, 0.0);
  tx.assign(n, 0.0), ty.assign(n, 0.0), tz.assign(n, 0.0);
  inv_inertia.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    inv_inertia[i] = 1.0 / (0.4 * mass[i] * radius[i] * radius[i]); // I = m d^2/10 = 2/5 m r^2
}

void ParticleStore::resize(std::size_t n) {
  for (auto* v : {&x, &y, &z, &vx, &vy, &vz, &fx, &fy, &fz, &radius, &mass, &inv_mass})
    v->resize(n, 0.0);
  id.resize(n, 0);
  if (rotation)
    for (auto* v : {&wx, &wy, &wz, &tx, &ty, &tz, &inv_inertia}) v->resize(n, 0.0);
}

std::size_t ParticleStore::add(double px, double py, double pz, double pvx, double pvy,
                               double pvz, double r, double density, std::int64_t pid) {
  const std::size_t i = size();
  resize(i + 1);
  x[i] = px, y[i] = py, z[i] = pz;
  vx[i] = pvx, vy[i] = pvy, vz[i] = pvz;
  radius[i] = r;
  id[i] = pid;
  set_mass(i, sphere_mass(density, r));
  return i;
}

void ParticleStore::set_mass(std::size_t i, double m) {
  mass[i] = m;
  inv_mass[i] = 1.0 / m;
  if (rotation) inv_inertia[i] = 1.0 / (0.4 * m * radius[i] * radius[i]);
}

void ParticleStore::swap(std::size_t a, std::size_t b) {
  for (auto* v : {&x, &y, &z, &vx, &vy, &vz, &fx, &fy, &fz, &radius, &mass, &inv_mass})
    std::swap((*v)[a], (*v)[b]);
  std::swap(id[a], id[b]);
  if (rotation)
    for (auto* v : {&wx, &wy, &wz, &tx, &ty, &tz, &inv_inertia}) std::swap((*v)[a], (*v)[b]);
}

void ParticleStore::permute(std::span<const std::uint32_t> order) {
  for (auto* v : {&x, &y, &z, &vx, &vy, &vz, &fx, &fy, &fz, &radius, &mass, &inv_mass})
    permute_field(*v, order, scratch_);
  permute_field(id, order, scratch_id_);
  if (rotation)
    for (auto* v : {&wx, &wy, &wz, &tx, &ty, &tz, &inv_inertia}) permute_field(*v, order, scratch_);
}

double ParticleStore::total_mass() const {
  double m = 0.0;
  for (double mi : mass) m += mi;
  return m;
}

} // namespace cfddem
