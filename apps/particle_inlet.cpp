#include "apps/particle_inlet.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>

#include <fmt/format.h>

#include "core/diameter_distribution.hpp"

namespace cfddem::apps {

namespace {

constexpr int kTries = 50; // positions tried for one particle before it waits a fluid step

// SplitMix64 (Steele, Lea & Flood 2014): a well-mixed seed from two counters.
std::uint64_t mix(std::uint64_t a, std::uint64_t b) {
  std::uint64_t z = a * 0x9E3779B97F4A7C15ULL + b + 0x632BE59BD9B4E019ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

double unit(std::mt19937_64& rng) {
  return static_cast<double>(rng() >> 11) * 0x1.0p-53;
}

} // namespace

ParticleInlet::ParticleInlet(const Scene& scene)
    : spec_(scene.inlet), particles_(scene.particles), domain_(scene.domain), geom_(scene.domain) {}

ParticleInlet::Sizes ParticleInlet::sizes() const {
  if (spec_.diameter > 0.0) // the inlet's own size or distribution
    return {spec_.diameters, spec_.diameter};
  return {particles_.diameters, particles_.diameter};
}

double ParticleInlet::diameter(std::int64_t k) const {
  const Sizes s = sizes();
  if (s.dist.fixed())
    return s.fixed;
  DiameterStream stream(s.dist, mix(spec_.seed, static_cast<std::uint64_t>(k)));
  return stream.next();
}

double ParticleInlet::mean_diameter() const {
  const Sizes s = sizes();
  return s.dist.fixed() ? s.fixed : s.dist.mean;
}

double ParticleInlet::largest_radius() const {
  if (spec_.mass_rate <= 0.0)
    return 0.0;
  const Sizes s = sizes();
  return 0.5 * (s.dist.fixed() ? s.fixed : s.dist.max);
}

int ParticleInlet::centres(double r, std::array<double, 3>& lo, std::array<double, 3>& hi) const {
  for (int a = 0; a < 3; ++a) {
    lo[a] = spec_.region_lo[a], hi[a] = spec_.region_hi[a];
    if (!geom_.periodic[a])
      lo[a] = std::max(lo[a], geom_.lo[a] + r), hi[a] = std::min(hi[a], geom_.hi[a] - r);
    if (hi[a] < lo[a])
      return a;
  }
  return -1;
}

std::string ParticleInlet::no_room(double r) const {
  std::array<double, 3> lo{}, hi{};
  if (const int a = centres(r, lo, hi); a >= 0)
    return fmt::format("along axis {} no centre of a particle of diameter {:.6g} m lies both in "
                       "the region [{:.6g}, {:.6g}] m and a radius from the walls at {:.6g} "
                       "and {:.6g} m",
                       a, 2.0 * r, spec_.region_lo[a], spec_.region_hi[a], geom_.lo[a],
                       geom_.hi[a]);
  if (domain_.cylinder())
    if (const std::string why = domain_.centres_beyond_cylinder(lo, hi, r); !why.empty())
      return "the region's nearest point to the cylinder's axis is " + why;
  return {};
}

double ParticleInlet::smallest_radius() const {
  if (spec_.mass_rate <= 0.0)
    return std::numeric_limits<double>::infinity();
  const Sizes s = sizes();
  return 0.5 * (s.dist.fixed() ? s.fixed : s.dist.min);
}

void ParticleInlet::start(InletState& st, const ParticleStore& p, std::size_t owned,
                          const Communicator& comm) const {
  if (st.next_id >= 0)
    return;
  std::int64_t top = -1;
  for (std::size_t i = 0; i < owned; ++i)
    top = std::max(top, p.id[i]);
  std::int64_t v[1] = {top};
  comm.max(std::span<std::int64_t>(v));
  st.next_id = v[0] + 1;
}

void ParticleInlet::queue(InletState& st, const ParticleStore& p,
                          std::span<const std::uint32_t> leaving, const Communicator& comm) const {
  if (!spec_.recycle)
    return;
  std::vector<double> id, r, m;
  for (const std::uint32_t i : leaving)
    id.push_back(static_cast<double>(p.id[i])), r.push_back(p.radius[i]), m.push_back(p.mass[i]);
  if (comm.size() > 1) {
    id = comm.gather(id), r = comm.gather(r), m = comm.gather(m);
    if (comm.rank() != 0)
      return;
  }
  std::vector<std::size_t> order(id.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::ranges::sort(order, [&](std::size_t a, std::size_t b) { return id[a] < id[b]; });
  for (const std::size_t k : order)
    st.queue_radius.push_back(r[k]), st.queue_mass.push_back(m[k]);
}

EnteringParticles ParticleInlet::enter(InletState& st, const ParticleStore& p, std::size_t owned,
                                       double dt_f, std::int64_t step,
                                       const Communicator& comm) const {
  EnteringParticles out;
  const bool root = comm.rank() == 0;
  // Rank 0 knows whether anything is due; every rank takes part in the gather only then.
  std::int64_t due[1] = {0};
  if (root) {
    st.owed += spec_.mass_rate * dt_f;
    const double next_mass =
        spec_.mass_rate > 0.0
            ? ParticleStore::sphere_mass(spec_.density, 0.5 * diameter(st.drawn))
            : std::numeric_limits<double>::infinity();
    due[0] = !st.queue_mass.empty() || st.owed >= next_mass ? 1 : 0;
  }
  if (comm.size() > 1)
    comm.sum(std::span<std::int64_t>(due));
  if (due[0] == 0)
    return out;

  // The particles near the region (within the largest radius that may enter plus their own).
  const double reach = std::max(
      largest_radius(), st.queue_radius.empty() ? 0.0 : *std::ranges::max_element(st.queue_radius));
  auto gap = [&](double q, int a, double pad) { // distance of q outside the padded interval
    const double lo = spec_.region_lo[a] - pad, hi = spec_.region_hi[a] + pad;
    double d = std::max({0.0, lo - q, q - hi});
    if (geom_.periodic[a])
      for (const double s : {-geom_.length[a], geom_.length[a]})
        d = std::min(d, std::max({0.0, lo - (q + s), (q + s) - hi}));
    return d;
  };
  std::vector<double> nx, ny, nz, nr;
  for (std::size_t i = 0; i < owned; ++i) {
    const double pad = reach + p.radius[i];
    if (gap(p.x[i], 0, pad) == 0.0 && gap(p.y[i], 1, pad) == 0.0 && gap(p.z[i], 2, pad) == 0.0)
      nx.push_back(p.x[i]), ny.push_back(p.y[i]), nz.push_back(p.z[i]), nr.push_back(p.radius[i]);
  }
  if (comm.size() > 1) {
    nx = comm.gather(nx), ny = comm.gather(ny), nz = comm.gather(nz), nr = comm.gather(nr);
    if (!root)
      return out;
  }

  std::mt19937_64 rng(mix(spec_.seed ^ 0x5EEDULL, static_cast<std::uint64_t>(step)));
  // One try at a place for a particle of radius r: inside the region and the domain (its walls
  // and a cylinder's), overlapping no particle near the region and none placed before it.
  auto place = [&](double r, double(&q)[3]) {
    std::array<double, 3> lo{}, hi{};
    if (centres(r, lo, hi) >= 0)
      return false;
    for (int a = 0; a < 3; ++a)
      q[a] = lo[a] + (hi[a] - lo[a]) * unit(rng);
    if (geom_.cylinder) {
      const double du = q[geom_.u] - geom_.centre_u, dw = q[geom_.w] - geom_.centre_w;
      if (std::sqrt(du * du + dw * dw) > geom_.radius - r)
        return false;
    }
    auto clear_of = [&](double x, double y, double z, double rj) {
      const double dx = geom_.image(q[0] - x, 0), dy = geom_.image(q[1] - y, 1),
                   dz = geom_.image(q[2] - z, 2);
      return dx * dx + dy * dy + dz * dz >= (r + rj) * (r + rj);
    };
    for (std::size_t j = 0; j < nx.size(); ++j)
      if (!clear_of(nx[j], ny[j], nz[j], nr[j]))
        return false;
    for (std::size_t j = 0; j < out.size(); ++j)
      if (!clear_of(out.x[j], out.y[j], out.z[j], out.radius[j]))
        return false;
    return true;
  };
  auto try_enter = [&](double r, double m) {
    double q[3];
    for (int t = 0; t < kTries; ++t)
      if (place(r, q)) {
        out.x.push_back(q[0]), out.y.push_back(q[1]), out.z.push_back(q[2]);
        out.radius.push_back(r), out.mass.push_back(m), out.id.push_back(st.next_id++);
        return true;
      }
    return false;
  };
  // The recycled particles first, in their order; then the new ones while their mass is due.
  std::size_t k = 0;
  while (k < st.queue_mass.size() && try_enter(st.queue_radius[k], st.queue_mass[k]))
    ++k;
  const bool queue_done = k == st.queue_mass.size();
  st.queue_radius.erase(st.queue_radius.begin(),
                        st.queue_radius.begin() + static_cast<std::ptrdiff_t>(k));
  st.queue_mass.erase(st.queue_mass.begin(),
                      st.queue_mass.begin() + static_cast<std::ptrdiff_t>(k));
  if (queue_done && spec_.mass_rate > 0.0) {
    for (;;) {
      const double r = 0.5 * diameter(st.drawn);
      const double m = ParticleStore::sphere_mass(spec_.density, r);
      if (st.owed < m || !try_enter(r, m))
        break;
      st.owed -= m;
      ++st.drawn;
    }
  }
  return out;
}

void widen_for_inlet(const Scene& scene, dem::ParticleRange& range) {
  const ParticleInlet in(scene);
  if (in.largest_radius() <= 0.0)
    return;
  // A mass rate needs a generated scene (core/scene.cpp), whose particles lie within the same
  // bounds: the range is the inlet's, on every rank count and at a restart alike.
  // With inlet.diameter or inlet.density of its own, the bounds of both kinds.
  const ParticleSpec& p = scene.particles;
  const double p0 = 0.5 * (p.diameters.fixed() ? p.diameter : p.diameters.min);
  const double p1 = 0.5 * (p.diameters.fixed() ? p.diameter : p.diameters.max);
  const double r0 = in.smallest_radius(), r1 = in.largest_radius();
  range.count = std::max<std::int64_t>(range.count, 1); // the step model reads a non-empty range
  range.r_min = std::min(p0, r0), range.r_max = std::max(p1, r1);
  range.m_min = std::min(ParticleStore::sphere_mass(p.density, p0),
                         ParticleStore::sphere_mass(scene.inlet.density, r0));
  range.m_max = std::max(ParticleStore::sphere_mass(p.density, p1),
                         ParticleStore::sphere_mass(scene.inlet.density, r1));
}

} // namespace cfddem::apps
