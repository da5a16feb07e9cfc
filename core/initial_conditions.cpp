#include "core/initial_conditions.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <functional>
#include <numbers>
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>
#include <unistd.h>

#include "core/error.hpp"

namespace cfddem {

namespace {
// A point's distance to the column's axis (domain.shape = "cylinder"), as the particle kernels
// measure it (dem/cylinder_wall.hpp).
double axis_distance(const DomainSpec& d, double x, double y, double z) {
  const double c[3] = {x, y, z};
  const auto [u, w] = d.cross_axes();
  const double du = c[u] - d.centre(u), dw = c[w] - d.centre(w);
  return std::sqrt(du * du + dw * dw);
}

// The diameter stream of a generator: a single size is particles.diameter (a Scene built in code
// may set only that), a distribution its own (core/diameter_distribution.hpp).
DiameterStream diameter_stream(const ParticleSpec& ps) {
  DiameterDistribution d = ps.diameters;
  if (d.fixed())
    d.mean = ps.diameter;
  return DiameterStream(d, ps.seed);
}
} // namespace

namespace {

// Bins of at least `cell` over the domain for overlap queries (serial set-up work, not the hot
// loop). Only occupied bins are stored: a hash from the bin to the head of its chain of particle
// indices, and one link per particle, so memory is O(particles) however large the domain (a
// dense array of bins over a dilute 100 mm box took gigabytes).
class PointGrid {
public:
  static constexpr std::size_t npos = static_cast<std::size_t>(-1);
  PointGrid(const DomainSpec& d, double cell) : d_(d) {
    for (int a = 0; a < 3; ++a) {
      // At most 2^21 bins per axis (the bin key packs three 21-bit indices); fewer, larger bins
      // still hold every neighbour within `cell` in the 27 around a point.
      const double n = std::floor(d.length(a) / cell);
      n_[a] = static_cast<int>(std::clamp(n, 1.0, static_cast<double>(1 << 21)));
      inv_[a] = n_[a] / d.length(a);
    }
  }
  std::array<int, 3> bin_of(double x, double y, double z) const {
    const double p[3] = {x, y, z};
    std::array<int, 3> b{};
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor((p[a] - d_.lo[a]) * inv_[a]);
      b[a] = static_cast<int>(std::clamp(f, 0.0, static_cast<double>(n_[a] - 1)));
    }
    return b;
  }
  void insert(std::size_t i, double x, double y, double z) {
    if (next_.size() <= i)
      next_.resize(i + 1, npos);
    auto [it, added] = head_.try_emplace(key(bin_of(x, y, z)), i);
    next_[i] = added ? npos : it->second;
    it->second = i;
  }
  // Visit every stored index in the 27 bins around (x, y, z), each bin once.
  template <class F> void for_near(double x, double y, double z, F&& f) const {
    auto b = bin_of(x, y, z);
    std::array<std::array<int, 3>, 3> idx{};
    std::array<int, 3> count{};
    for (int a = 0; a < 3; ++a) {
      for (int o = -1; o <= 1; ++o) {
        int c = b[a] + o;
        if (c < 0 || c >= n_[a]) {
          if (!d_.periodic[a])
            continue;
          c = (c + n_[a]) % n_[a];
        }
        if (std::find(idx[a].begin(), idx[a].begin() + count[a], c) == idx[a].begin() + count[a])
          idx[a][static_cast<std::size_t>(count[a]++)] = c;
      }
    }
    for (int i = 0; i < count[0]; ++i)
      for (int j = 0; j < count[1]; ++j)
        for (int k = 0; k < count[2]; ++k) {
          const auto it = head_.find(
              key({idx[0][static_cast<std::size_t>(i)], idx[1][static_cast<std::size_t>(j)],
                   idx[2][static_cast<std::size_t>(k)]}));
          if (it == head_.end())
            continue;
          for (std::size_t q = it->second; q != npos; q = next_[q])
            f(q);
        }
  }

private:
  static std::uint64_t key(std::array<int, 3> b) {
    return (static_cast<std::uint64_t>(b[2]) << 42) | (static_cast<std::uint64_t>(b[1]) << 21) |
           static_cast<std::uint64_t>(b[0]);
  }
  DomainSpec d_;
  std::array<int, 3> n_{};
  std::array<double, 3> inv_{};
  std::unordered_map<std::uint64_t, std::size_t> head_; // occupied bin -> last particle in it
  std::vector<std::size_t> next_;                       // particle -> the one before it in its bin
};

double min_image(double dx, double length, bool periodic) {
  if (periodic)
    dx -= length * std::nearbyint(dx / length);
  return dx;
}

double gap(const ParticleStore& p, std::size_t i, std::size_t j, const DomainSpec& d) {
  const double dx = min_image(p.x[j] - p.x[i], d.length(0), d.periodic[0]);
  const double dy = min_image(p.y[j] - p.y[i], d.length(1), d.periodic[1]);
  const double dz = min_image(p.z[j] - p.z[i], d.length(2), d.periodic[2]);
  return std::sqrt(dx * dx + dy * dy + dz * dz) - (p.radius[i] + p.radius[j]);
}

// Random close packing of equal spheres (Scott & Kilgour 1969; Torquato, Truskett & Debenedetti,
// PRL 84, 2064 (2000)): no placement fits more (kRandomSequentialLimit, the header: what random
// placement reaches).
constexpr double kRandomClosePacking = 0.64;
// The memory a generated particle costs at set-up and in the run (store, lists, scheme state),
// an upper estimate used only to refuse counts that cannot fit at all.
constexpr double kBytesPerParticle = 1024;

std::function<void(const std::string&)>& setup_progress_sink() {
  static std::function<void(const std::string&)> sink;
  return sink;
}

// A progress line every output.progress_seconds of wall time while a set-up runs long.
class SetupProgress {
public:
  SetupProgress(const Scene& s, const char* what)
      : what_(what), every_(s.output.progress_seconds), t0_(std::chrono::steady_clock::now()),
        last_(t0_) {}
  void report(std::int64_t done, std::int64_t total, std::int64_t attempts) {
    const auto& sink = setup_progress_sink();
    if (!sink)
      return;
    const auto now = std::chrono::steady_clock::now();
    if (std::chrono::duration<double>(now - last_).count() < every_)
      return;
    last_ = now;
    sink(fmt::format("set-up ({}): {} of {} particles placed ({:.1f}%), {} attempts, {:.0f} s",
                     what_, done, total,
                     100.0 * static_cast<double>(done) / static_cast<double>(total), attempts,
                     std::chrono::duration<double>(now - t0_).count()));
  }

private:
  const char* what_;
  double every_;
  std::chrono::steady_clock::time_point t0_, last_;
};

} // namespace

void set_setup_progress(std::function<void(const std::string&)> sink) {
  setup_progress_sink() = std::move(sink);
}

namespace {

// Diameters a distribution's mean volume is taken from: enough for the solid fraction to 1% or
// better, few enough to take milliseconds (drawing all of 1e10 took minutes before a refusal).
constexpr std::int64_t kVolumeSample = 100000;

// The mean sphere volume of the generator's particles: exact for one size and for counts up to
// kVolumeSample; beyond, the mean over the stream's first kVolumeSample diameters (the particles'
// own, in id order: the stream is not sorted by size).
double mean_particle_volume(const ParticleSpec& ps) {
  if (ps.diameters.fixed())
    return std::numbers::pi / 6.0 * ps.diameter * ps.diameter * ps.diameter;
  DiameterStream d = diameter_stream(ps);
  const std::int64_t n = std::min(ps.count, kVolumeSample);
  double sum = 0.0;
  for (std::int64_t k = 0; k < n; ++k) {
    const double dk = d.next();
    sum += std::numbers::pi / 6.0 * dk * dk * dk;
  }
  return sum / static_cast<double>(n);
}

} // namespace

void check_packing_feasible(const Scene& s) {
  const auto& ps = s.particles;
  if (!ps.file.empty() || ps.count <= 0)
    return;
  double region = 1.0;
  for (int a = 0; a < 3; ++a)
    region *= ps.region_hi[a] - ps.region_lo[a];
  if (s.domain.cylinder()) {
    // Only the part of the region inside the column holds particles: at most its cross-section.
    const auto [u, w] = s.domain.cross_axes();
    const double across = (ps.region_hi[u] - ps.region_lo[u]) * (ps.region_hi[w] - ps.region_lo[w]);
    region *= std::min(1.0, s.domain.cylinder_area() / across);
  }
  const double solids = static_cast<double>(ps.count) * mean_particle_volume(ps);
  const double phi = solids / region;
  const auto fits = [&](double limit) {
    return static_cast<std::int64_t>(limit * region / (solids / static_cast<double>(ps.count)));
  };
  if (phi > kRandomClosePacking)
    throw ConfigError(
        "scene key 'particles.count'",
        fmt::format("{} particles of diameter up to {} m ask for a solid fraction of {:.3g} "
                    "in the region; no packing holds more than random close packing, {} "
                    "(about {} particles here): lower particles.count or enlarge the region",
                    ps.count, ps.diameter, phi, kRandomClosePacking, fits(kRandomClosePacking)));
  const double bytes = static_cast<double>(ps.count) * kBytesPerParticle;
  const double memory = static_cast<double>(::sysconf(_SC_PHYS_PAGES)) *
                        static_cast<double>(::sysconf(_SC_PAGE_SIZE));
  if (memory > 0 && bytes > memory)
    throw ConfigError("scene key 'particles.count'",
                      fmt::format("{} particles need about {:.3g} GB, more than this machine's "
                                  "{:.3g} GB of memory",
                                  ps.count, bytes / 1e9, memory / 1e9));
  if (ps.placement == "random" && phi > kRandomSequentialLimit)
    throw ConfigError("scene key 'particles.count'",
                      fmt::format("solid fraction {:.3g} in the region: random placement (random "
                                  "sequential addition) jams near {} (about {} particles here); "
                                  "use particles.placement = \"lattice\", or fewer particles, "
                                  "or a larger region",
                                  phi, kRandomSequentialLimit, fits(kRandomSequentialLimit)));
}

namespace {

// The diameters of particles 0..count-1 (core/diameter_distribution.hpp).
std::vector<double> draw_diameters(const ParticleSpec& ps) {
  DiameterStream stream = diameter_stream(ps);
  std::vector<double> d(static_cast<std::size_t>(ps.count));
  for (double& x : d)
    x = stream.next();
  return d;
}

void place_random(ParticleStore& p, const Scene& s) {
  const auto& ps = s.particles;
  const std::vector<double> diameter = draw_diameters(ps);
  // Random sequential addition; with a distribution the largest particles go first (a large
  // sphere finds no hole left among small ones long before a small one runs out of room), and
  // the store is put back in id order at the end.
  std::vector<std::int64_t> order(diameter.size());
  std::iota(order.begin(), order.end(), std::int64_t{0});
  if (!ps.diameters.fixed())
    std::stable_sort(order.begin(), order.end(), [&](std::int64_t a, std::int64_t b) {
      return diameter[static_cast<std::size_t>(a)] > diameter[static_cast<std::size_t>(b)];
    });
  std::mt19937_64 rng(ps.seed);
  // Centres keep their radius from non-periodic region faces so no particle starts in a wall.
  std::array<bool, 3> full_periodic{};
  for (int a = 0; a < 3; ++a) {
    full_periodic[a] = s.domain.periodic[a] && ps.region_lo[a] == s.domain.lo[a] &&
                       ps.region_hi[a] == s.domain.hi[a];
    if (ps.region_hi[a] - ps.region_lo[a] <= (full_periodic[a] ? 0.0 : ps.diameter))
      throw ConfigError(
          "scene key 'particles.region_hi'",
          fmt::format("region too thin for particles of diameter {} (axis {})", ps.diameter, a));
  }
  PointGrid grid(s.domain, ps.diameter);
  const bool column = s.domain.cylinder();
  if (column && ps.count > 0) {
    // A region whose centres all lie beyond the column's curved wall placed nothing in 1000
    // tries per particle and was refused as if it were full (random placement's saturation).
    const double r = 0.5 * *std::max_element(diameter.begin(), diameter.end());
    std::array<double, 3> lo{}, hi{}; // the centres' box
    for (int a = 0; a < 3; ++a) {
      lo[a] = ps.region_lo[a] + (full_periodic[a] ? 0.0 : r);
      hi[a] = ps.region_hi[a] - (full_periodic[a] ? 0.0 : r);
    }
    if (const std::string why = s.domain.centres_beyond_cylinder(lo, hi, r); !why.empty())
      throw ConfigError("scene keys 'particles.region_lo', 'particles.region_hi'",
                        "the region lies outside the cylinder: its nearest centre to the axis is " +
                            why);
  }
  const std::int64_t max_attempts = 1000 * ps.count + 100000;
  std::int64_t attempts = 0;
  SetupProgress progress(s, "random placement");
  while (static_cast<std::int64_t>(p.size()) < ps.count) {
    if ((attempts & 4095) == 0)
      progress.report(static_cast<std::int64_t>(p.size()), ps.count, attempts);
    if (++attempts > max_attempts)
      throw ConfigError("scene key 'particles.count'",
                        fmt::format("could place only {} of {} non-overlapping particles in the "
                                    "region (random placement saturates near 38% solids; use "
                                    "particles.placement = \"lattice\" or a larger region)",
                                    p.size(), ps.count));
    const std::int64_t k = order[p.size()];
    const double r = 0.5 * diameter[static_cast<std::size_t>(k)];
    // (The distributions are stateless: drawing through fresh ones with the same range gives
    // the values one reused distribution gives.)
    std::array<double, 3> c{};
    for (std::size_t a = 0; a < 3; ++a) {
      const double m = full_periodic[a] ? 0.0 : r;
      c[a] = std::uniform_real_distribution<double>(ps.region_lo[a] + m, ps.region_hi[a] - m)(rng);
    }
    const double x = c[0], y = c[1], z = c[2];
    // In a column the centre keeps its radius from the curved wall too (rho <= R - r).
    if (column && !(axis_distance(s.domain, x, y, z) <= s.domain.cylinder_radius - r))
      continue;
    bool free = true;
    const std::size_t cand = p.add(x, y, z, 0, 0, 0, r, ps.density, k);
    grid.for_near(x, y, z, [&](std::size_t q) {
      if (free && gap(p, cand, q, s.domain) <= 0.0)
        free = false;
    });
    if (free) {
      grid.insert(cand, x, y, z);
    } else {
      p.resize(cand);
    }
  }
  if (!ps.diameters.fixed()) {
    std::vector<std::uint32_t> by_id(p.size());
    for (std::size_t i = 0; i < p.size(); ++i)
      by_id[static_cast<std::size_t>(p.id[i])] = static_cast<std::uint32_t>(i);
    p.permute(by_id);
  }
}

// Particle k of the lattice is added when keep(k) (ids stay k): a rank builds its own share.
template <class Keep> void place_lattice(ParticleStore& p, const Scene& s, Keep keep) {
  const auto& ps = s.particles;
  const double d = ps.diameter;
  std::array<int, 3> n{};
  std::array<double, 3> spacing{};
  // Simple cubic lattice with spacing >= d filling the region; particles fill it in x, y, z order.
  for (int a = 0; a < 3; ++a) {
    n[a] = static_cast<int>(std::floor((ps.region_hi[a] - ps.region_lo[a]) / (d * 1.0000001)));
    if (n[a] < 1)
      n[a] = 0;
  }
  for (int a = 0; a < 3; ++a)
    spacing[a] = (ps.region_hi[a] - ps.region_lo[a]) / n[a];
  auto site = [&](int a, int i) { return ps.region_lo[a] + (i + 0.5) * spacing[a]; };
  // In a column only the sites whose particle stays inside it (rho <= R - d/2).
  const bool column = s.domain.cylinder();
  auto inside = [&](int ix, int iy, int iz) {
    return !column || axis_distance(s.domain, site(0, ix), site(1, iy), site(2, iz)) <=
                          s.domain.cylinder_radius - 0.5 * d;
  };
  std::int64_t capacity = static_cast<std::int64_t>(n[0]) * n[1] * n[2];
  if (column) {
    capacity = 0;
    for (int iz = 0; iz < n[2]; ++iz)
      for (int iy = 0; iy < n[1]; ++iy)
        for (int ix = 0; ix < n[0]; ++ix)
          capacity += inside(ix, iy, iz) ? 1 : 0;
  }
  if (capacity < ps.count)
    throw ConfigError("scene key 'particles.count'",
                      fmt::format("a cubic lattice of spacing d fits {} particles in the region{}, "
                                  "{} were asked for",
                                  capacity,
                                  column
                                      ? fmt::format(" and inside the cylinder (of its {} sites)",
                                                    static_cast<std::int64_t>(n[0]) * n[1] * n[2])
                                      : std::string(),
                                  ps.count));
  // Sites are spaced by the largest diameter; each particle's own diameter comes from the
  // stream, drawn for every site in id order (kept or not) so a rank's share gets the whole
  // set's values.
  DiameterStream diameter = diameter_stream(ps);
  std::int64_t k = 0;
  for (int iz = 0; iz < n[2] && k < ps.count; ++iz)
    for (int iy = 0; iy < n[1] && k < ps.count; ++iy)
      for (int ix = 0; ix < n[0] && k < ps.count; ++ix) {
        if (!inside(ix, iy, iz))
          continue;
        if (const double dk = diameter.next(); keep(k))
          p.add(site(0, ix), site(1, iy), site(2, iz), 0, 0, 0, 0.5 * dk, ps.density, k);
        ++k;
      }
}

} // namespace

// assign_thermal_velocities for a share of n generated particles of equal mass m: p holds the
// particles with the ids `ids` (increasing), and gets exactly the velocities the whole set would
// get. The normal stream is drawn twice over all n (the mean, then the variance, summed in id
// order as the whole-set version does) without storing it: O(n) time, O(share) memory.
void assign_thermal_velocities_share(ParticleStore& p, std::int64_t n, const ParticleSpec& ps,
                                     double density, double temperature,
                                     const std::array<double, 3>& mean, std::uint64_t seed) {
  if (n == 0)
    return;
  const double sigma = std::sqrt(std::max(temperature, 0.0));
  double mt = 0, px = 0, py = 0, pz = 0;
  {
    std::mt19937_64 rng(seed ^ 0x9e3779b97f4a7c15ULL);
    std::normal_distribution<double> g(0.0, sigma);
    DiameterStream diameter = diameter_stream(ps);
    for (std::int64_t k = 0; k < n; ++k) {
      const double a = g(rng), b = g(rng), c = g(rng);
      const double m = ParticleStore::sphere_mass(density, 0.5 * diameter.next());
      mt += m, px += m * a, py += m * b, pz += m * c;
    }
  }
  double sq = 0;
  std::size_t mine = 0;
  {
    std::mt19937_64 rng(seed ^ 0x9e3779b97f4a7c15ULL);
    std::normal_distribution<double> g(0.0, sigma);
    for (std::int64_t k = 0; k < n; ++k) {
      double a = g(rng), b = g(rng), c = g(rng);
      a -= px / mt, b -= py / mt, c -= pz / mt;
      sq += a * a + b * b + c * c;
      if (mine < p.size() && p.id[mine] == k)
        p.vx[mine] = a, p.vy[mine] = b, p.vz[mine] = c, ++mine;
    }
  }
  const double scale =
      (sq > 0 && n > 1) ? std::sqrt(temperature / (sq / (3.0 * static_cast<double>(n)))) : 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    p.vx[i] = p.vx[i] * scale + mean[0];
    p.vy[i] = p.vy[i] * scale + mean[1];
    p.vz[i] = p.vz[i] * scale + mean[2];
  }
}

void assign_thermal_velocities(ParticleStore& p, double temperature,
                               const std::array<double, 3>& mean, std::uint64_t seed) {
  const std::size_t n = p.size();
  if (n == 0)
    return;
  std::mt19937_64 rng(seed ^ 0x9e3779b97f4a7c15ULL);
  std::normal_distribution<double> g(0.0, std::sqrt(std::max(temperature, 0.0)));
  for (std::size_t i = 0; i < n; ++i)
    p.vx[i] = g(rng), p.vy[i] = g(rng), p.vz[i] = g(rng);
  // Remove the mass-weighted mean, then rescale to T0 exactly (as the peers' generator does).
  double mt = 0, px = 0, py = 0, pz = 0;
  for (std::size_t i = 0; i < n; ++i)
    mt += p.mass[i], px += p.mass[i] * p.vx[i], py += p.mass[i] * p.vy[i],
        pz += p.mass[i] * p.vz[i];
  double sq = 0;
  for (std::size_t i = 0; i < n; ++i) {
    p.vx[i] -= px / mt, p.vy[i] -= py / mt, p.vz[i] -= pz / mt;
    sq += p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
  }
  const double scale = (sq > 0 && n > 1) ? std::sqrt(temperature / (sq / (3.0 * n))) : 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    p.vx[i] = p.vx[i] * scale + mean[0];
    p.vy[i] = p.vy[i] * scale + mean[1];
    p.vz[i] = p.vz[i] * scale + mean[2];
  }
}

ParticleStore read_particle_csv(const std::string& path) {
  return read_particle_csv_rows(path, [](std::int64_t) { return true; });
}

ParticleStore read_particle_csv_rows(const std::string& path,
                                     const std::function<bool(std::int64_t)>& keep) {
  std::ifstream in(path);
  if (!in)
    throw ConfigError(path, "cannot open the particle file (scene key 'particles.file')");
  std::string line;
  if (!std::getline(in, line))
    throw ConfigError(path, "empty file: expected a header row");
  // Spreadsheets' "CSV UTF-8" export starts the file with a byte-order mark (EF BB BF); it is
  // not part of the first column's name.
  if (line.starts_with("\xEF\xBB\xBF"))
    line.erase(0, 3);
  const std::vector<std::string> wanted = {"x", "y", "z", "vx", "vy", "vz", "diameter", "density"};
  std::vector<int> col(wanted.size(), -1);
  {
    std::stringstream hs(line);
    std::string name;
    int c = 0;
    while (std::getline(hs, name, ',')) {
      name.erase(std::remove_if(name.begin(), name.end(), ::isspace), name.end());
      auto it = std::find(wanted.begin(), wanted.end(), name);
      if (it == wanted.end())
        throw ConfigError(path + " line 1", fmt::format("unknown column '{}' (expected {})", name,
                                                        "x,y,z,vx,vy,vz,diameter,density"));
      if (col[it - wanted.begin()] >= 0) // a repeated column would index past each row
        throw ConfigError(path + " line 1", fmt::format("column '{}' appears twice", name));
      col[it - wanted.begin()] = c++;
    }
    for (std::size_t k = 0; k < wanted.size(); ++k)
      if (col[k] < 0)
        throw ConfigError(path + " line 1", fmt::format("missing column '{}'", wanted[k]));
  }
  ParticleStore p;
  int lineno = 1;
  std::int64_t row = 0;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.find_first_not_of(" \t\r") == std::string::npos)
      continue;
    std::vector<double> v;
    std::stringstream ls(line);
    std::string cell;
    while (std::getline(ls, cell, ',')) {
      char* end = nullptr;
      const double val = std::strtod(cell.c_str(), &end);
      while (end && *end && std::isspace(static_cast<unsigned char>(*end)))
        ++end;
      if (cell.empty() || !end || *end != '\0' || !std::isfinite(val))
        throw ConfigError(fmt::format("{} line {}", path, lineno),
                          fmt::format("'{}' is not a finite number", cell));
      v.push_back(val);
    }
    if (v.size() != wanted.size())
      throw ConfigError(fmt::format("{} line {}", path, lineno),
                        fmt::format("expected {} values, got {}", wanted.size(), v.size()));
    const double d = v[col[6]], rho = v[col[7]];
    if (!(d > 0) || !(rho > 0))
      throw ConfigError(fmt::format("{} line {}", path, lineno),
                        "diameter and density must be > 0");
    if (keep(row))
      p.add(v[col[0]], v[col[1]], v[col[2]], v[col[3]], v[col[4]], v[col[5]], 0.5 * d, rho, row);
    ++row;
  }
  return p;
}

namespace {

// f(i, j, gap) for every pair i < j closer than the largest diameter (serial set-up work).
template <class F> void for_close_pairs(const ParticleStore& p, const DomainSpec& domain, F&& f) {
  if (p.size() < 2)
    return;
  double dmax = 0;
  for (double r : p.radius)
    dmax = std::max(dmax, 2 * r);
  PointGrid grid(domain, dmax);
  for (std::size_t i = 0; i < p.size(); ++i)
    grid.insert(i, p.x[i], p.y[i], p.z[i]);
  for (std::size_t i = 0; i < p.size(); ++i) {
    grid.for_near(p.x[i], p.y[i], p.z[i], [&](std::size_t j) {
      if (j > i)
        f(i, j, gap(p, i, j, domain));
    });
  }
}

// Two particles on the same centre have no contact normal: their force is 0/0 (NaN positions at
// the first step), so even particles.allow_overlap cannot take them.
void check_distinct_centres(const ParticleStore& p, const DomainSpec& domain) {
  for_close_pairs(p, domain, [&](std::size_t i, std::size_t j, double g) {
    if (g + p.radius[i] + p.radius[j] <= 0.0)
      throw ConfigError("initial particles",
                        fmt::format("particles {} and {} have the same centre ({:.6g}, {:.6g}, "
                                    "{:.6g}): their contact has no direction, even with "
                                    "particles.allow_overlap = true",
                                    p.id[i], p.id[j], p.x[i], p.y[i], p.z[i]));
  });
}

} // namespace

void check_no_overlap(const ParticleStore& p, const DomainSpec& domain) {
  for_close_pairs(p, domain, [&](std::size_t i, std::size_t j, double g) {
    if (g < 0.0)
      throw ConfigError(
          "initial particles",
          fmt::format("particles {} at ({:.6g}, {:.6g}, {:.6g}) and {} at ({:.6g}, {:.6g}, "
                      "{:.6g}) overlap by {:.3g} m (set particles.allow_overlap = true to "
                      "accept it)",
                      p.id[i], p.x[i], p.y[i], p.z[i], p.id[j], p.x[j], p.y[j], p.z[j], -g));
  });
}

namespace {

// Every particle must start inside the domain (walls are at lo/hi of non-periodic axes).
void check_inside(const ParticleStore& p, const Scene& s) {
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double c[3] = {p.x[i], p.y[i], p.z[i]};
    for (int a = 0; a < 3; ++a) {
      if (!(c[a] >= s.domain.lo[a] && c[a] <= s.domain.hi[a]))
        throw ConfigError(s.particles.file.empty() ? "particles" : s.particles.file,
                          fmt::format("particle {} at ({}, {}, {}) lies outside the domain "
                                      "(domain.lo, domain.hi)",
                                      p.id[i], c[0], c[1], c[2]));
      if (!(2 * p.radius[i] < s.domain.length(a)))
        throw ConfigError(s.particles.file.empty() ? "particles" : s.particles.file,
                          fmt::format("particle {} of diameter {} does not fit in the domain "
                                      "(axis {} is {} m long: domain.lo, domain.hi)",
                                      p.id[i], 2 * p.radius[i], a, s.domain.length(a)));
    }
    if (s.domain.cylinder() &&
        !(axis_distance(s.domain, c[0], c[1], c[2]) <= s.domain.cylinder_radius &&
          p.radius[i] < s.domain.cylinder_radius))
      throw ConfigError(s.particles.file.empty() ? "particles" : s.particles.file,
                        fmt::format("particle {} at ({}, {}, {}) of radius {} m does not lie "
                                    "inside the cylinder (domain.cylinder_radius = {} m)",
                                    p.id[i], c[0], c[1], c[2], p.radius[i],
                                    s.domain.cylinder_radius));
  }
}

// A particle cutting into a wall starts with the wall's spring compressed by the cut: a deep cut
// stopped the run at step 0 as "too fast for the spring", which is the wrong advice. Refused as a
// pair overlap is, and accepted alike with particles.allow_overlap.
void check_walls(const ParticleStore& p, const Scene& s) {
  static const char* walls[3][2] = {{"x_lo", "x_hi"}, {"y_lo", "y_hi"}, {"z_lo", "z_hi"}};
  const bool column = s.domain.cylinder();
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double c[3] = {p.x[i], p.y[i], p.z[i]};
    for (std::size_t a = 0; a < 3; ++a) {
      // A column's curved wall replaces the planar walls across it (checked below).
      if (s.domain.periodic[a] || (column && static_cast<int>(a) != s.domain.cylinder_axis))
        continue;
      const double cut[2] = {p.radius[i] - (c[a] - s.domain.lo[a]),
                             p.radius[i] - (s.domain.hi[a] - c[a])};
      // (A placed particle's centre may round to a hair inside its radius.)
      for (int side = 0; side < 2; ++side)
        if (cut[side] > 1e-9 * p.radius[i])
          throw ConfigError(s.particles.file.empty() ? "particles" : s.particles.file,
                            fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) of radius {:.6g} "
                                        "m overlaps wall {} by {:.3g} m (set "
                                        "particles.allow_overlap = true to accept it)",
                                        p.id[i], c[0], c[1], c[2], p.radius[i], walls[a][side],
                                        cut[side]));
    }
    if (!column)
      continue;
    const double cut = p.radius[i] + axis_distance(s.domain, c[0], c[1], c[2]) -
                       s.domain.cylinder_radius;
    if (cut > 1e-9 * p.radius[i])
      throw ConfigError(s.particles.file.empty() ? "particles" : s.particles.file,
                        fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) of radius {:.6g} m "
                                    "overlaps the cylinder's wall by {:.3g} m (set "
                                    "particles.allow_overlap = true to accept it)",
                                    p.id[i], c[0], c[1], c[2], p.radius[i], cut));
  }
}

} // namespace

ParticleStore make_initial_particles(const Scene& s) {
  ParticleStore p;
  if (!s.particles.file.empty()) {
    p = read_particle_csv(s.particles.file);
  } else {
    check_packing_feasible(s);
    if (s.particles.placement == "lattice") {
      place_lattice(p, s, [](std::int64_t) { return true; });
    } else {
      place_random(p, s);
    }
    assign_thermal_velocities(p, s.particles.temperature, s.particles.velocity, s.particles.seed);
  }
  check_inside(p, s);
  if (!s.particles.allow_overlap) {
    check_walls(p, s);
    check_no_overlap(p, s.domain);
  } else {
    check_distinct_centres(p, s.domain);
  }
  return p;
}

ParticleStore make_initial_share(const Scene& s, int rank, int ranks) {
  if (ranks < 1 || rank < 0 || rank >= ranks)
    throw std::invalid_argument(fmt::format("make_initial_share: rank {} of {}", rank, ranks));
  const auto r = static_cast<std::int64_t>(rank), nr = static_cast<std::int64_t>(ranks);
  auto mine = [r, nr](std::int64_t k) { return k % nr == r; };
  ParticleStore p;
  if (!s.particles.file.empty()) {
    if (!s.particles.allow_overlap) {
      // The overlap test needs every particle: read them all, check, keep the share.
      p = make_initial_particles(s);
    } else {
      p = read_particle_csv_rows(s.particles.file, mine);
      check_inside(p, s);
    }
  } else if (s.particles.placement == "lattice") {
    check_packing_feasible(s);
    // Lattice sites are spaced by more than a diameter: no overlap to check.
    place_lattice(p, s, mine);
    assign_thermal_velocities_share(p, s.particles.count, s.particles, s.particles.density,
                                    s.particles.temperature, s.particles.velocity,
                                    s.particles.seed);
    check_inside(p, s);
    return p;
  } else {
    // Random placement rejects each candidate against those placed before it: the whole set is
    // generated on every rank (positions for n particles) and only the share kept.
    p = make_initial_particles(s);
  }
  std::vector<std::uint32_t> keep;
  for (std::size_t i = 0; i < p.size(); ++i)
    if (mine(p.id[i]))
      keep.push_back(static_cast<std::uint32_t>(i));
  p.permute(keep);
  return p;
}

} // namespace cfddem
