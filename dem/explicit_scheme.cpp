#include "dem/explicit_scheme.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/partitioner.h>

#include "core/error.hpp"
#include "dem/contact_damping.hpp"
#include "dem/contact_kernels.hpp"

namespace cfddem::dem {

namespace {
constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
enum class Fault { none = 0, nan, overlap, speed, left_domain };
} // namespace

// What one pass found: the largest displacement since the neighbor build, and the first (lowest
// index) particle that failed a check. Both combine order-independently (max, min), so the
// report does not depend on how TBB split the range.
struct ExplicitScheme::Report {
  std::int64_t moved = 0; // particles farther than skin/2 from where the list was built
  std::uint32_t bad = kNone;
  std::uint32_t partner = kNone;
  Fault fault = Fault::none;
  double value = 0.0;
  void flag(std::uint32_t i, Fault f, double v, std::uint32_t j = kNone) {
    if (i < bad) bad = i, fault = f, value = v, partner = j;
  }
  void join(const Report& o) {
    moved += o.moved;
    if (o.bad < bad) bad = o.bad, fault = o.fault, value = o.value, partner = o.partner;
  }
};

StepModel make_step_model(const Scene& s, const ParticleStore& p) {
  StepModel m;
  const auto& d = s.dem;
  m.gravity = s.gravity;
  m.pair = {d.spring_constant, dashpot_coefficient(d.spring_constant, d.restitution)};
  m.wall = {d.wall_spring_constant, dashpot_coefficient(d.wall_spring_constant, d.wall_restitution)};
  m.friction = d.friction > 0.0 || d.wall_friction > 0.0;
  m.pair_t = {d.tangential_stiffness_ratio * d.spring_constant,
              d.tangential_damping_ratio * m.pair.eta_coef, d.friction};
  m.wall_t = {d.tangential_stiffness_ratio * d.wall_spring_constant,
              d.tangential_damping_ratio * m.wall.eta_coef, d.wall_friction};
  m.max_overlap = d.max_overlap;
  double m_min = std::numeric_limits<double>::infinity();
  double r_min = std::numeric_limits<double>::infinity(), r_max = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    m_min = std::min(m_min, p.mass[i]);
    r_min = std::min(r_min, p.radius[i]);
    r_max = std::max(r_max, p.radius[i]);
  }
  if (p.size() == 0) m_min = 1.0, r_min = r_max = 1.0;
  m.r_min = r_min;
  m.uniform_mass = p.size() > 0 && std::all_of(p.mass.begin(), p.mass.end(),
                                                [&](double mi) { return mi == p.mass[0]; });
  if (m.uniform_mass) {
    m.uniform_meff = 0.5 * p.mass[0];
    m.uniform_eta = m.pair.eta_coef * std::sqrt(m.uniform_meff); // physics.md §2: eta_n
  }
  const double k_max = std::max(d.spring_constant, d.wall_spring_constant);
  const double tau_p = std::sqrt(m_min / k_max);
  m.dt = d.dt > 0.0 ? d.dt : tau_p * d.dt_factor;
  // Stiffest oscillator: two of the lightest particles (m_eff = m/2) or one against a wall.
  const double omega = std::max(std::sqrt(2.0 * d.spring_constant / m_min),
                                std::sqrt(d.wall_spring_constant / m_min));
  if (omega * m.dt >= 2.0)
    throw RunError(fmt::format(
        "unstable time step: omega dt = {:.4g} >= 2 for the stiffest contact (dt = {:.4g} s, "
        "dem.dt_factor = {}, dem.dt = {}); velocity Verlet on a spring needs omega dt < 2, and "
        "accuracy needs far less (dem.dt_factor = 0.02 gives 0.028)",
        omega * m.dt, m.dt, d.dt_factor, d.dt));
  m.skin = d.neighbor_skin > 0 ? d.neighbor_skin : 0.5 * r_max; // 0.25 d_max (the peers' skin)
  return m;
}

ExplicitScheme::ExplicitScheme(const Scene& scene, ParticleStore& particles, PhaseTimer& timer)
    : scene_(scene), p_(particles), timer_(timer), geom_(scene.domain),
      model_(make_step_model(scene, particles)) {
  if (model_.friction) p_.enable_rotation();
}

void ExplicitScheme::rebuild() {
  PhaseTimer::Scope t(timer_, Phase::neighbor);
  if (!model_.friction) {
    list_.build(p_, geom_, model_.skin);
  } else {
    // Carry the tangential history of each pair across the rebuild, keyed by particle ids.
    std::unordered_map<std::int64_t, std::uint32_t> old_index;
    old_index.reserve(p_.size());
    for (std::size_t i = 0; i < p_.size(); ++i) old_index[p_.id[i]] = static_cast<std::uint32_t>(i);
    const std::vector<std::uint32_t> old_off(list_.offsets().begin(), list_.offsets().end());
    const std::vector<std::uint32_t> old_nb(list_.neighbors().begin(), list_.neighbors().end());
    std::vector<std::int64_t> old_ids(p_.id);
    std::vector<double> ohx(std::move(hx_)), ohy(std::move(hy_)), ohz(std::move(hz_));
    list_.build(p_, geom_, model_.skin);
    const auto off = list_.offsets();
    const auto nb = list_.neighbors();
    hx_.assign(nb.size(), 0.0), hy_.assign(nb.size(), 0.0), hz_.assign(nb.size(), 0.0);
    if (!old_off.empty()) {
      for (std::size_t i = 0; i + 1 < off.size(); ++i) {
        const std::uint32_t oi = old_index[p_.id[i]];
        for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
          const std::int64_t jid = p_.id[nb[k]];
          for (std::uint32_t q = old_off[oi]; q < old_off[oi + 1]; ++q)
            if (old_ids[old_nb[q]] == jid) {
              hx_[k] = ohx[q], hy_[k] = ohy[q], hz_[k] = ohz[q];
              break;
            }
        }
      }
    }
  }
  ext_.permute(list_.order()); // the build permuted the store: external forces follow
  // Only particles with a row get their contact force rewritten each step: clear the rest.
  std::fill(p_.fx.begin(), p_.fx.end(), 0.0);
  std::fill(p_.fy.begin(), p_.fy.end(), 0.0);
  std::fill(p_.fz.begin(), p_.fz.end(), 0.0);
  if (p_.rotation) {
    std::fill(p_.tx.begin(), p_.tx.end(), 0.0);
    std::fill(p_.ty.begin(), p_.ty.end(), 0.0);
    std::fill(p_.tz.begin(), p_.tz.end(), 0.0);
  }
  ++builds_;
  need_rebuild_ = false;
}

template <bool Friction> void ExplicitScheme::contact_pass(double dt, Report& out) {
  const double* __restrict x = p_.x.data();
  const double* __restrict y = p_.y.data();
  const double* __restrict z = p_.z.data();
  const double* __restrict vx = p_.vx.data();
  const double* __restrict vy = p_.vy.data();
  const double* __restrict vz = p_.vz.data();
  const double* __restrict rad = p_.radius.data();
  const double* __restrict mass = p_.mass.data();
  double* __restrict fx = p_.fx.data();
  double* __restrict fy = p_.fy.data();
  double* __restrict fz = p_.fz.data();
  const std::uint32_t* __restrict off = list_.offsets().data();
  const std::uint32_t* __restrict nb = list_.neighbors().data();
  const std::uint32_t* __restrict act = list_.active().data();
  const DomainGeometry g = geom_;
  const StepModel m = model_;

  // Forces on particle i from its row, summed in the row's (sorted) order.
  const std::uint32_t* __restrict wrap = list_.wrap_begin().data();
  auto body = [&](const tbb::blocked_range<std::size_t>& r, Report rep) {
    // Locals, not captures: the compiler keeps them in registers across the stores below.
    const double* __restrict lx = x;
    const double* __restrict ly = y;
    const double* __restrict lz = z;
    const double* __restrict lr = rad;
    const std::uint32_t* __restrict lnb = nb;
    for (std::size_t q = r.begin(); q != r.end(); ++q) {
      const std::uint32_t i = act[q];
      const double xi = x[i], yi = y[i], zi = z[i];
      const double vxi = vx[i], vyi = vy[i], vzi = vz[i], ri = rad[i], mi = mass[i];
      double ax = 0.0, ay = 0.0, az = 0.0;
      [[maybe_unused]] double tqx = 0.0, tqy = 0.0, tqz = 0.0;
      // One pair: the separation (dx, dy, dz) is already the minimum image.
      auto pair = [&](std::uint32_t k, std::uint32_t j, double dx, double dy, double dz) {
        const double r2 = dx * dx + dy * dy + dz * dz;
        const double rs = ri + lr[j];
        if (r2 >= rs * rs) {
          if constexpr (Friction) hx_[k] = hy_[k] = hz_[k] = 0.0;
          return;
        }
        const double dist = std::sqrt(r2);
        const double inv = 1.0 / dist;
        const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
        const double delta = rs - dist;
        const double dvx = vxi - vx[j], dvy = vyi - vy[j], dvz = vzi - vz[j];
        const double vn = dvx * nx + dvy * ny + dvz * nz;
        // Equal masses (the common case) skip the divide and square root of m_eff.
        const double meff = contact_meff(m, mi, mass[j]);
        const double fn = contact_normal_force(m, meff, delta, vn);
        ax -= fn * nx, ay -= fn * ny, az -= fn * nz;
        if (delta > m.max_overlap * std::min(ri, rad[j]))
          rep.flag(i, Fault::overlap, delta / std::min(ri, rad[j]), j);
        if constexpr (Friction) {
          // Contact-point relative velocity: v_i - v_j + (r_i w_i + r_j w_j) x n (physics.md §2).
          const double sx = ri * p_.wx[i] + rad[j] * p_.wx[j];
          const double sy = ri * p_.wy[i] + rad[j] * p_.wy[j];
          const double sz = ri * p_.wz[i] + rad[j] * p_.wz[j];
          const double rvx = dvx + (sy * nz - sz * ny), rvy = dvy + (sz * nx - sx * nz),
                       rvz = dvz + (sx * ny - sy * nx);
          const double rvn = rvx * nx + rvy * ny + rvz * nz;
          const double nvec[3] = {nx, ny, nz};
          const double vt[3] = {rvx - rvn * nx, rvy - rvn * ny, rvz - rvn * nz};
          double xi3[3] = {hx_[k], hy_[k], hz_[k]}, ft[3];
          tangential_force(m.pair_t, meff, dt, std::abs(fn), nvec, vt, xi3, ft);
          hx_[k] = xi3[0], hy_[k] = xi3[1], hz_[k] = xi3[2];
          ax += ft[0], ay += ft[1], az += ft[2];
          // Torque on i: (r_i n) x F_t.
          tqx += ri * (ny * ft[2] - nz * ft[1]);
          tqy += ri * (nz * ft[0] - nx * ft[2]);
          tqz += ri * (nx * ft[1] - ny * ft[0]);
        }
      };
      // Pairs inside the box first (no periodic image needed), then those across a face.
      const std::uint32_t kw = wrap[i];
      for (std::uint32_t k = off[i]; k < kw; ++k) {
        const std::uint32_t j = lnb[k];
        pair(k, j, lx[j] - xi, ly[j] - yi, lz[j] - zi);
      }
      for (std::uint32_t k = kw; k < off[i + 1]; ++k) {
        const std::uint32_t j = lnb[k];
        pair(k, j, g.image(lx[j] - xi, 0), g.image(ly[j] - yi, 1), g.image(lz[j] - zi, 2));
      }
      fx[i] = ax, fy[i] = ay, fz[i] = az;
      if constexpr (Friction) p_.tx[i] = tqx, p_.ty[i] = tqy, p_.tz[i] = tqz;
    }
    return rep;
  };
  const std::size_t n = list_.active().size();
  const tbb::blocked_range<std::size_t> all(0, n, 256);
  if (n <= 1024) {
    out.join(body(all, Report{})); // small work: no task overhead
  } else {
    out.join(tbb::parallel_reduce(
        all, Report{}, body,
        [](Report a, const Report& b) {
          a.join(b);
          return a;
        },
        tbb::simple_partitioner{}));
  }
}

// Planar walls at lo and hi of every non-periodic axis: force (and torque, with friction) added
// to particle i's contact force. Outward wall normal s = -1 at lo, +1 at hi.
template <bool Friction>
static void add_wall_forces(const DomainGeometry& g, const StepModel& m, ParticleStore& p,
                            std::size_t i, double f[3], double tq[3], auto&& flag) {
  const double pos[3] = {p.x[i], p.y[i], p.z[i]}, vel[3] = {p.vx[i], p.vy[i], p.vz[i]};
  const double ri = p.radius[i], mi = p.mass[i];
  for (int a = 0; a < 3; ++a) {
    if (g.periodic[a]) continue;
    for (int side = 0; side < 2; ++side) {
      const double s = side ? 1.0 : -1.0;
      const double delta = side ? ri - (g.hi[a] - pos[a]) : ri - (pos[a] - g.lo[a]);
      if (delta <= 0.0) continue;
      const double fn = normal_force(m.wall, mi, delta, s * vel[a]);
      f[a] -= s * fn;
      if (delta > m.max_overlap * ri) flag(delta / ri);
      if constexpr (Friction) {
        double nvec[3] = {0, 0, 0};
        nvec[a] = s;
        // Slip of the contact point: v_i + w_i x (r_i n) (the wall is at rest).
        const double w[3] = {p.wx[i], p.wy[i], p.wz[i]};
        const double rv[3] = {vel[0] + ri * (w[1] * nvec[2] - w[2] * nvec[1]),
                              vel[1] + ri * (w[2] * nvec[0] - w[0] * nvec[2]),
                              vel[2] + ri * (w[0] * nvec[1] - w[1] * nvec[0])};
        const double rvn = rv[a] * s;
        const double vt[3] = {rv[0] - rvn * nvec[0], rv[1] - rvn * nvec[1], rv[2] - rvn * nvec[2]};
        // Walls keep no tangential history: a dashpot capped by the Coulomb limit (MFIX-Exa's
        // convention of sliding friction, physics.md §2).
        double xi3[3] = {0, 0, 0}, ft[3];
        tangential_force(m.wall_t, mi, 0.0, std::abs(fn), nvec, vt, xi3, ft);
        for (int b = 0; b < 3; ++b) f[b] += ft[b];
        tq[0] += ri * (nvec[1] * ft[2] - nvec[2] * ft[1]);
        tq[1] += ri * (nvec[2] * ft[0] - nvec[0] * ft[2]);
        tq[2] += ri * (nvec[0] * ft[1] - nvec[1] * ft[0]);
      }
    }
  }
}

// Velocity Verlet update of particles [0, n) of the given arrays: v += (F/m) dt + g dt,
// x += v dt. Adds 1 to `moved` if some particle is now farther than skin/2 from its build
// position, and to `fails` if some particle moves more than r_min per step (or is NaN).
// The two checks are AND-reductions of sign bits (+-1.0 per particle): integer reductions that
// vectorize with no floating-point reassociation and no in-order dependency chain (a max, a
// floating-point count, or int64 counts of double compares all vectorize badly or not at all
// on baseline x86-64).
// With External, a per-particle external force (the gas's, held over the sub-cycle) is added.
template <bool External>
static void integrate_range(double* __restrict x, double* __restrict y, double* __restrict z,
                            double* __restrict vx, double* __restrict vy, double* __restrict vz,
                            const double* __restrict fx, const double* __restrict fy,
                            const double* __restrict fz, const double* __restrict ex,
                            const double* __restrict ey, const double* __restrict ez,
                            const double* __restrict im,
                            const double* __restrict rx, const double* __restrict ry,
                            const double* __restrict rz, std::size_t n, double h, double gx,
                            double gy, double gz, double skin2, double lim2, double& moved,
                            double& fails) {
  std::uint64_t still = ~std::uint64_t{0}, slow = ~std::uint64_t{0}; // sign bit: all fine
  for (std::size_t i = 0; i < n; ++i) {
    const double s = im[i] * h;
    double ux, uy, uz;
    if constexpr (External) {
      ux = vx[i] + (fx[i] + ex[i]) * s + gx;
      uy = vy[i] + (fy[i] + ey[i]) * s + gy;
      uz = vz[i] + (fz[i] + ez[i]) * s + gz;
    } else {
      ux = vx[i] + fx[i] * s + gx;
      uy = vy[i] + fy[i] * s + gy;
      uz = vz[i] + fz[i] * s + gz;
    }
    vx[i] = ux, vy[i] = uy, vz[i] = uz;
    const double px = x[i] + ux * h, py = y[i] + uy * h, pz = z[i] + uz * h;
    x[i] = px, y[i] = py, z[i] = pz;
    const double dx = px - rx[i], dy = py - ry[i], dz = pz - rz[i];
    still &= std::bit_cast<std::uint64_t>(dx * dx + dy * dy + dz * dz > skin2 ? 1.0 : -1.0);
    slow &= std::bit_cast<std::uint64_t>(ux * ux + uy * uy + uz * uz <= lim2 ? -1.0 : 1.0);
  }
  moved += (still >> 63) ? 0.0 : 1.0;
  fails += (slow >> 63) ? 0.0 : 1.0; // a NaN compares false: it fails too
}

// v(n+1/2) = v(n-1/2) + (F/m + g) dt, x(n+1) = x(n) + v(n+1/2) dt over every particle. Without
// walls the loop has no branch and vectorizes; the checks are folded into reductions and the
// offending particle is searched for only when one fails.
template <bool Walls, bool Friction, bool External>
void ExplicitScheme::update_pass(double dt, Report& out) {
  const std::size_t n = p_.size();
  const DomainGeometry g = geom_;
  const StepModel m = model_;
  const double gx = m.gravity[0] * dt, gy = m.gravity[1] * dt, gz = m.gravity[2] * dt;
  const double vmax2 = dt > 0 ? (m.r_min / dt) * (m.r_min / dt) : INFINITY;
  const double half_skin2 = 0.25 * m.skin * m.skin;
  const double* __restrict xr = list_.x_ref().data();
  const double* __restrict yr = list_.y_ref().data();
  const double* __restrict zr = list_.z_ref().data();

  struct Partial {
    std::int64_t moved = 0; // particles now farther than skin/2 from their build position
    std::int64_t failures = 0;
    Report walls;
  };
  auto body = [&](const tbb::blocked_range<std::size_t>& r, Partial acc) {
    double* __restrict x = p_.x.data();
    double* __restrict y = p_.y.data();
    double* __restrict z = p_.z.data();
    double* __restrict vx = p_.vx.data();
    double* __restrict vy = p_.vy.data();
    double* __restrict vz = p_.vz.data();
    double* __restrict fx = p_.fx.data();
    double* __restrict fy = p_.fy.data();
    double* __restrict fz = p_.fz.data();
    const double* __restrict im = p_.inv_mass.data();
    [[maybe_unused]] const double* __restrict fex = ext_.x.data();
    [[maybe_unused]] const double* __restrict fey = ext_.y.data();
    [[maybe_unused]] const double* __restrict fez = ext_.z.data();
    if constexpr (Walls) {
      // A particle without a neighbor row keeps last step's total (contact + wall) in f: start
      // it from zero. Rows are fixed between builds, so this is exact.
      const std::uint32_t* __restrict off = list_.offsets().data();
      for (std::size_t i = r.begin(); i != r.end(); ++i) {
        const bool row = off[i + 1] > off[i];
        double f[3] = {row ? fx[i] : 0.0, row ? fy[i] : 0.0, row ? fz[i] : 0.0};
        double tq[3] = {0, 0, 0};
        if constexpr (Friction)
          if (row) tq[0] = p_.tx[i], tq[1] = p_.ty[i], tq[2] = p_.tz[i];
        add_wall_forces<Friction>(g, m, p_, i, f, tq, [&](double v) {
          acc.walls.flag(static_cast<std::uint32_t>(i), Fault::overlap, v);
        });
        fx[i] = f[0], fy[i] = f[1], fz[i] = f[2];
        if constexpr (Friction) p_.tx[i] = tq[0], p_.ty[i] = tq[1], p_.tz[i] = tq[2];
      }
    }
    const std::size_t b = r.begin(), e = r.end();
    double moved = 0.0, fails = 0.0;
    integrate_range<External>(x + b, y + b, z + b, vx + b, vy + b, vz + b, fx + b, fy + b, fz + b,
                              External ? fex + b : nullptr, External ? fey + b : nullptr,
                              External ? fez + b : nullptr, im + b, xr + b, yr + b, zr + b, e - b,
                              dt, gx, gy, gz, half_skin2, vmax2, moved, fails);
    if constexpr (Friction) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) {
        const double s = p_.inv_inertia[i] * dt;
        p_.wx[i] += p_.tx[i] * s, p_.wy[i] += p_.ty[i] * s, p_.wz[i] += p_.tz[i] * s;
      }
    }
    if constexpr (Walls) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) {
        const double q[3] = {x[i], y[i], z[i]};
        for (int a = 0; a < 3; ++a)
          fails += !g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a]);
      }
    }
    acc.moved += static_cast<std::int64_t>(moved);
    acc.failures += static_cast<std::int64_t>(fails);
    return acc;
  };
  const tbb::blocked_range<std::size_t> all(0, n, 4096);
  Partial total;
  auto join = [](Partial a, const Partial& b) {
    a.moved += b.moved;
    a.failures += b.failures;
    a.walls.join(b.walls);
    return a;
  };
  if (n <= 8192) {
    total = body(all, Partial{});
  } else {
    total = tbb::parallel_reduce(all, Partial{}, body, join, tbb::static_partitioner{});
  }
  out.moved = total.moved;
  out.join(total.walls);
  if (total.failures > 0) {
    // Rare path: name the first particle that failed, deterministically.
    for (std::size_t i = 0; i < n; ++i) {
      const double u2 = p_.vx[i] * p_.vx[i] + p_.vy[i] * p_.vy[i] + p_.vz[i] * p_.vz[i];
      const double q[3] = {p_.x[i], p_.y[i], p_.z[i]};
      const auto ii = static_cast<std::uint32_t>(i);
      if (!std::isfinite(u2) || !std::isfinite(q[0] + q[1] + q[2])) {
        out.flag(ii, Fault::nan, u2);
      } else if (!(u2 <= vmax2)) {
        out.flag(ii, Fault::speed, std::sqrt(u2));
      } else {
        for (int a = 0; a < 3; ++a)
          if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a]))
            out.flag(ii, Fault::left_domain, q[a]);
      }
      if (out.bad != kNone) break;
    }
  }
}

template <bool Walls> void ExplicitScheme::update(double dt, Report& rep) {
  if (model_.friction) {
    ext_.active() ? update_pass<Walls, true, true>(dt, rep) : update_pass<Walls, true, false>(dt, rep);
  } else {
    ext_.active() ? update_pass<Walls, false, true>(dt, rep)
              : update_pass<Walls, false, false>(dt, rep);
  }
}

void ExplicitScheme::set_external_force(std::span<const double> fx, std::span<const double> fy,
                                        std::span<const double> fz) {
  ext_.set(fx, fy, fz, p_.size());
}

void ExplicitScheme::evaluate_and_update(double dt, Report& rep) {
  const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
  {
    PhaseTimer::Scope t(timer_, Phase::force);
    model_.friction ? contact_pass<true>(dt, rep) : contact_pass<false>(dt, rep);
  }
  // Wall forces are evaluated inside the update pass and timed with it.
  PhaseTimer::Scope t(timer_, Phase::integrate);
  walls ? update<true>(dt, rep) : update<false>(dt, rep);
}

void ExplicitScheme::raise(const Report& r, double t) const {
  const std::uint32_t i = r.bad;
  const std::string who = fmt::format("particle {} at ({:.6g}, {:.6g}, {:.6g}) m", p_.id[i],
                                      p_.x[i], p_.y[i], p_.z[i]);
  std::string why;
  switch (r.fault) {
  case Fault::nan:
    why = "position or velocity is not finite (NaN/inf): the step is unstable";
    break;
  case Fault::overlap:
    why = r.partner == kNone
              ? fmt::format("overlap with a wall is {:.3g} of its radius (dem.max_overlap = {}): "
                            "the impact is too fast for the spring (raise k or lower dt)",
                            r.value, model_.max_overlap)
              : fmt::format("overlap with particle {} is {:.3g} of the smaller radius "
                            "(dem.max_overlap = {}): the impact is too fast for the spring "
                            "(raise k or lower dt)",
                            p_.id[r.partner], r.value, model_.max_overlap);
    break;
  case Fault::speed:
    why = fmt::format("speed {:.4g} m/s moves it more than the smallest radius in one step "
                      "(dt = {:.4g} s): contacts could be missed (tunnelling)",
                      r.value, model_.dt);
    break;
  case Fault::left_domain:
    why = fmt::format("left the domain through a wall (coordinate {:.6g} m)", r.value);
    break;
  case Fault::none:
    break;
  }
  throw RunError(fmt::format("t = {:.9g} s, step {}: {}: {}", t, steps_, who, why));
}

void ExplicitScheme::start() {
  rebuild();
  // Forces at t = 0 with v(0) (dt = 0 leaves x and v unchanged), then v(-dt/2) = v(0) - a(0) dt/2.
  Report rep;
  evaluate_and_update(0.0, rep);
  if (rep.bad != kNone && rep.fault == Fault::overlap) raise(rep, 0.0);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < p_.size(); ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    p_.vx[i] -= ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    p_.vy[i] -= ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    p_.vz[i] -= ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
    if (model_.friction) {
      p_.wx[i] -= p_.tx[i] * p_.inv_inertia[i] * h;
      p_.wy[i] -= p_.ty[i] * p_.inv_inertia[i] * h;
      p_.wz[i] -= p_.tz[i] * p_.inv_inertia[i] * h;
    }
  }
}

void ExplicitScheme::record_synchronised() {
  // x(n) and v(n) = v(n-1/2) + a(n) dt/2, with a(n) from the forces just evaluated.
  const std::size_t n = p_.size();
  sx_ = p_.x, sy_ = p_.y, sz_ = p_.z;
  svx_.resize(n), svy_.resize(n), svz_.resize(n);
  const double h = 0.5 * model_.dt;
  for (std::size_t i = 0; i < n; ++i) {
    const double e[3] = {ext_.active() ? ext_.x[i] : 0.0, ext_.active() ? ext_.y[i] : 0.0,
                         ext_.active() ? ext_.z[i] : 0.0};
    svx_[i] = p_.vx[i] + ((p_.fx[i] + e[0]) * p_.inv_mass[i] + model_.gravity[0]) * h;
    svy_[i] = p_.vy[i] + ((p_.fy[i] + e[1]) * p_.inv_mass[i] + model_.gravity[1]) * h;
    svz_[i] = p_.vz[i] + ((p_.fz[i] + e[2]) * p_.inv_mass[i] + model_.gravity[2]) * h;
  }
}

void ExplicitScheme::step(bool record) {
  if (need_rebuild_) rebuild();
  Report rep;
  if (!record) {
    evaluate_and_update(model_.dt, rep);
  } else {
    // Split so the state at time n can be recorded between the force and the update.
    const bool walls = !(geom_.periodic[0] && geom_.periodic[1] && geom_.periodic[2]);
    const bool fr = model_.friction;
    {
      PhaseTimer::Scope t(timer_, Phase::force);
      fr ? contact_pass<true>(model_.dt, rep) : contact_pass<false>(model_.dt, rep);
    }
    PhaseTimer::Scope t(timer_, Phase::integrate);
    if (walls) {
      // Wall forces are added inside the update pass; record after a force-only wall pass would
      // double count, so record with the wall forces applied by a dt = 0 update.
      fr ? update_pass<true, true, false>(0.0, rep) : update_pass<true, false, false>(0.0, rep);
      record_synchronised();
      // The dt = 0 pass left x, v unchanged and F including walls; finish with a pure update.
      update<false>(model_.dt, rep);
    } else {
      record_synchronised();
      update<false>(model_.dt, rep);
    }
  }
  if (rep.bad != kNone) raise(rep, time());
  ++steps_;
  particle_steps_ += static_cast<std::int64_t>(p_.size());
  pair_evaluations_ += static_cast<std::int64_t>(list_.pair_count());
  if (rep.moved > 0) need_rebuild_ = true;
}

ExplicitScheme::State ExplicitScheme::save_state() const {
  State s;
  s.offsets.assign(list_.offsets().begin(), list_.offsets().end());
  s.neighbors.assign(list_.neighbors().begin(), list_.neighbors().end());
  s.x_ref.assign(list_.x_ref().begin(), list_.x_ref().end());
  s.y_ref.assign(list_.y_ref().begin(), list_.y_ref().end());
  s.z_ref.assign(list_.z_ref().begin(), list_.z_ref().end());
  s.hx = hx_, s.hy = hy_, s.hz = hz_;
  s.skin = list_.skin();
  s.need_rebuild = need_rebuild_;
  s.steps = steps_, s.particle_steps = particle_steps_;
  s.pair_evaluations = pair_evaluations_, s.builds = builds_;
  return s;
}

void ExplicitScheme::restore_state(State s) {
  const std::size_t n = p_.size();
  const bool listed = !s.offsets.empty();
  if (listed && (s.offsets.size() != n + 1 || s.offsets.front() != 0 ||
                 s.offsets.back() != s.neighbors.size() || s.x_ref.size() != n ||
                 s.y_ref.size() != n || s.z_ref.size() != n))
    throw RunError("checkpoint: the neighbor list does not fit the particles");
  for (std::size_t i = 0; listed && i < n; ++i)
    if (s.offsets[i + 1] < s.offsets[i])
      throw RunError("checkpoint: the neighbor list offsets are not monotonic");
  for (const std::uint32_t j : s.neighbors)
    if (j >= n) throw RunError("checkpoint: a neighbor index is out of range");
  if (model_.friction && (s.hx.size() != s.neighbors.size() || s.hy.size() != s.neighbors.size() ||
                          s.hz.size() != s.neighbors.size()))
    throw RunError("checkpoint: the tangential history does not fit the neighbor list");
  list_.restore(std::move(s.offsets), std::move(s.neighbors), std::move(s.x_ref),
                std::move(s.y_ref), std::move(s.z_ref), s.skin, geom_);
  hx_ = std::move(s.hx), hy_ = std::move(s.hy), hz_ = std::move(s.hz);
  need_rebuild_ = s.need_rebuild || !listed;
  steps_ = s.steps, particle_steps_ = s.particle_steps;
  pair_evaluations_ = s.pair_evaluations, builds_ = s.builds;
}

} // namespace cfddem::dem
