// The islands scheme's kernels (dem/islands_scheme.hpp), one copy for its one-rank and R-rank
// paths: the speed bound, the link and wall-tie tests, an island's raised bound, the contact
// forces on island members, the fine steps of an island, free flight and the fault search. They
// take small views of the particle columns and know nothing of ranks or threads, except the
// fine steps of a giant island, which run each pass as a nested parallel loop.
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "core/particle_store.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/external_force.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/friction_kernels.hpp"
#include "dem/scheme_support.hpp"
#include "dem/step_model.hpp"

namespace cfddem::dem::islands {

// The columns a fine step reads and writes, as spans over the store's arrays (every one the
// store's length): the store's, the scheme's half steps (hp) and the held external force (empty
// without one); with friction the spins and torques, and 1 / I (empty without rotation).
struct Columns {
  std::span<double> x, y, z, vx, vy, vz, fx, fy, fz, hp;
  std::span<const double> im, radius, mass;
  std::span<const std::int64_t> id;
  std::span<const double> ex, ey, ez;
  std::span<double> wx, wy, wz, tx, ty, tz;
  std::span<const double> ii;
};
inline Columns columns(ParticleStore& p, std::vector<double>& hprev, const ExternalForce& e) {
  const bool on = e.active();
  const bool spin = p.rotation;
  auto opt = [](bool present, auto& v) {
    return present ? std::span(v) : std::span<std::remove_reference_t<decltype(v[0])>>{};
  };
  return {p.x,
          p.y,
          p.z,
          p.vx,
          p.vy,
          p.vz,
          p.fx,
          p.fy,
          p.fz,
          hprev,
          p.inv_mass,
          p.radius,
          p.mass,
          p.id,
          opt(on, e.x),
          opt(on, e.y),
          opt(on, e.z),
          opt(spin, p.wx),
          opt(spin, p.wy),
          opt(spin, p.wz),
          opt(spin, p.tx),
          opt(spin, p.ty),
          opt(spin, p.tz),
          opt(spin, p.inv_inertia)};
}

// Neighbor rows in CSR form. wrap[i]: where row i's pairs across a periodic face begin (the
// Verlet list's order); without it (R ranks) every pair takes the minimum image.
struct Rows {
  std::span<const std::uint32_t> off, nb, wrap; // wrap empty on R ranks
};

// What the contact pass of island members needs besides the columns: the rows, each particle's
// island (label) and the contact law; with friction the tangential history per row entry.
struct ContactView {
  Columns c;
  Rows rows;
  std::span<const std::uint32_t> label;
  const DomainGeometry* geom;
  const StepModel* model;
  std::span<double> hx, hy, hz; // empty without friction
};

// |F_ext,i / m_i + g|.
template <bool External>
inline double acceleration(const Columns& c, const std::array<double, 3>& g, std::size_t i) {
  double ax = g[0], ay = g[1], az = g[2];
  if constexpr (External) {
    ax += c.ex[i] * c.im[i], ay += c.ey[i] * c.im[i], az += c.ez[i] * c.im[i];
  }
  return std::sqrt(ax * ax + ay * ay + az * az);
}

// The speed bound of particles [0, n) over a sub-iteration of dt_sp (header of
// islands_scheme.hpp): s_i = |v_i| + |F_ext,i / m_i + g| (h_prev,i + dt_sp).
inline void speed_bounds(const Columns& c, std::size_t n, const std::array<double, 3>& g,
                         double dt_sp, double* __restrict b) {
  const double* __restrict vx = c.vx.data();
  const double* __restrict vy = c.vy.data();
  const double* __restrict vz = c.vz.data();
  const double* __restrict hp = c.hp.data();
  if (c.ex.empty()) {
    // Gravity alone: one acceleration for all.
    const double a = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    for (std::size_t i = 0; i < n; ++i)
      b[i] = std::sqrt(vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]) + a * (hp[i] + dt_sp);
    return;
  }
  for (std::size_t i = 0; i < n; ++i)
    b[i] = std::sqrt(vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i]) +
           acceleration<true>(c, g, i) * (hp[i] + dt_sp);
}

// The first-contact rule the link and tie tests solve for the time: a gap (its margin already
// taken off) closes at a closing speed (the two bounds, or one against a wall) no earlier than
// gap / speed; now when it is within the margin, never at rest. The length choice's histogram
// (raised bounds, every partner) and an island's entry time (own bounds, its members) read it.
inline double closing_time(double gap, double speed) {
  return gap <= 0.0 ? 0.0 : speed > 0.0 ? gap / speed : std::numeric_limits<double>::infinity();
}
// A particle's gap to the nearer wall of axis a, less its radius.
inline double wall_gap(double pos, double lo, double hi, double r) {
  return std::min(pos - lo, hi - pos) - r;
}

// The link test: particles i and j (squared separation d2) could touch within dt_sp.
inline bool may_touch(double d2, double bi, double bj, double ri, double rj, double dt_sp,
                      double margin) {
  const double reach = (bi + bj) * dt_sp + margin + ri + rj;
  return d2 < reach * reach;
}
// The wall tie: a particle at `pos` could reach the wall lo or hi of its axis within dt_sp.
inline bool may_reach_wall(double pos, double lo, double hi, double r, double b, double dt_sp,
                           double margin) {
  return wall_gap(pos, lo, hi, r) < b * dt_sp + margin;
}
// The tie to the curved wall (domain.shape = "cylinder"): the particle at (x, y, z) could reach
// it within dt_sp (its gap R - rho - r shrinks no faster than its speed bound b).
inline bool may_reach_cylinder(const DomainGeometry& g, double x, double y, double z, double r,
                               double b, double dt_sp, double margin) {
  return cylinder_gap(g, x, y, z, r) < b * dt_sp + margin;
}
// An island's raised bound: the speed that takes its whole energy E on its lightest member, plus
// what the external forces add over the sub-iteration: s_max = sqrt(2 E / m_min) + a_max
// (h_prev,max + dt_sp).
inline double island_speed(double energy, double m_min, double a_max, double hp_max, double dt_sp) {
  return std::sqrt(2.0 * energy / m_min) + a_max * (hp_max + dt_sp);
}

// The largest reach (displacement since the list's build plus the bound over the sub-iteration)
// and the second largest, over particles [0, n). A pair missing from a list of skin s needs two
// reaches adding up to s to touch (the list-expiry rule). With NanIsInfinite a NaN reach makes
// the largest infinite (the R-rank rule reduces it over ranks); without, a NaN is left to the
// fault checks.
struct Reaches {
  double first = 0.0, second = 0.0;
};
template <bool NanIsInfinite>
Reaches largest_reaches(const double* __restrict x, const double* __restrict y,
                        const double* __restrict z, const double* __restrict xr,
                        const double* __restrict yr, const double* __restrict zr,
                        const double* __restrict b, double dt_sp, std::size_t n) {
  double top1 = 0.0, top2 = 0.0;
  bool nan = false;
  for (std::size_t i = 0; i < n; ++i) {
    const double ex = x[i] - xr[i], ey = y[i] - yr[i], ez = z[i] - zr[i];
    const double reach = std::sqrt(ex * ex + ey * ey + ez * ez) + b[i] * dt_sp;
    if (!(reach <= top2)) { // NaN lands here
      if constexpr (NanIsInfinite)
        nan = nan || reach != reach;
      if (!(reach <= top1))
        top2 = top1, top1 = reach;
      else
        top2 = reach;
    }
  }
  if (nan)
    top1 = std::numeric_limits<double>::infinity();
  return {top1, top2};
}

// The walls' force on member i (and torque, with friction; w its spin), added to (ax, ay, az)
// after its pairs; overlaps into the island's tallies. With Cylinder the curved wall's too.
template <bool Friction, bool Cylinder = false>
inline void add_member_walls(const ContactView& v, std::uint32_t i, double& ax, double& ay,
                             double& az, const double w[3], double tq[3], double& max_ratio,
                             std::int64_t& violations) {
  const StepModel& m = *v.model;
  const double ri = v.c.radius[i], mi = v.c.mass[i];
  double f[3] = {ax, ay, az};
  const double pos[3] = {v.c.x[i], v.c.y[i], v.c.z[i]}, vel[3] = {v.c.vx[i], v.c.vy[i], v.c.vz[i]};
  add_wall_contacts<Friction, Cylinder>(
      *v.geom, m.wall, m.wall_t, pos, vel, ri, [&] { return mi; },
      [&](double s[3]) { s[0] = w[0], s[1] = w[1], s[2] = w[2]; }, f, tq,
      [&](double delta) {
        max_ratio = std::max(max_ratio, delta / ri);
        violations += delta > m.max_overlap * ri;
      });
  ax = f[0], ay = f[1], az = f[2];
}

// Contact and wall forces on particles u0..u1 (idx[u] with Indexed, else u itself; the explicit
// scheme's contact law), from their row partners in island `island` (with Label; all partners
// without). Returns the pairs evaluated, each once: (i, j) with j > i (ById: id[j] > id[i], so
// that a pair with a ghost end counts on one rank only). With Friction the tangential springs of
// the entries evaluated advance over the step hk and the torques are written too
// (dem/friction_kernels.hpp: the explicit scheme's arithmetic). Cylinder: the curved wall acts
// too (contact_forces chooses once per call).
template <bool Label, bool Indexed, bool Wrap, bool ById, bool Friction, bool Cylinder>
std::int64_t contact_forces_of(const ContactView& v, const std::uint32_t* idx, std::uint32_t u0,
                               std::uint32_t u1, std::uint32_t island, double& max_ratio_out,
                               std::int64_t& violations_out, [[maybe_unused]] double hk = 0.0) {
  const std::uint32_t* __restrict off = v.rows.off.data();
  const std::uint32_t* __restrict nb = v.rows.nb.data();
  const std::uint32_t* __restrict wrap = v.rows.wrap.data();
  const std::uint32_t* __restrict label = v.label.data();
  // References (a copy per particle would cost more than it saves): the loop stores only to
  // locals, so their fields stay in registers.
  const DomainGeometry& g = *v.geom;
  const StepModel& m = *v.model;
  const double* __restrict x = v.c.x.data();
  const double* __restrict y = v.c.y.data();
  const double* __restrict z = v.c.z.data();
  const double* __restrict vx = v.c.vx.data();
  const double* __restrict vy = v.c.vy.data();
  const double* __restrict vz = v.c.vz.data();
  const double* __restrict rad = v.c.radius.data();
  const double* __restrict mass = v.c.mass.data();
  const std::int64_t* __restrict id = v.c.id.data();
  double* __restrict fxo = v.c.fx.data();
  double* __restrict fyo = v.c.fy.data();
  double* __restrict fzo = v.c.fz.data();
  double max_ratio = max_ratio_out;
  std::int64_t pairs = 0, violations = 0;
  for (std::uint32_t u = u0; u < u1; ++u) {
    const std::uint32_t i = Indexed ? idx[u] : u;
    const double xi = x[i], yi = y[i], zi = z[i], vxi = vx[i], vyi = vy[i], vzi = vz[i];
    const double ri = rad[i], mi = mass[i];
    double ax = 0.0, ay = 0.0, az = 0.0;
    [[maybe_unused]] double tq[3] = {0.0, 0.0, 0.0};
    [[maybe_unused]] double wi[3] = {0.0, 0.0, 0.0};
    if constexpr (Friction)
      wi[0] = v.c.wx[i], wi[1] = v.c.wy[i], wi[2] = v.c.wz[i];
    auto pair = [&]([[maybe_unused]] std::uint32_t k, std::uint32_t j, double dx, double dy,
                    double dz) {
      if constexpr (ById)
        pairs += id[j] > id[i];
      else
        pairs += j > i;
      double delta;
      if constexpr (Friction) {
        const double wj[3] = {v.c.wx[j], v.c.wy[j], v.c.wz[j]};
        double h[3] = {v.hx[k], v.hy[k], v.hz[k]}, a[3] = {ax, ay, az};
        delta = add_frictional_contact(m, dx, dy, dz, ri, rad[j], mi, mass[j], vxi - vx[j],
                                       vyi - vy[j], vzi - vz[j], wi, wj, hk, h, a, tq);
        v.hx[k] = h[0], v.hy[k] = h[1], v.hz[k] = h[2];
        ax = a[0], ay = a[1], az = a[2];
      } else {
        delta = add_normal_contact(m, dx, dy, dz, ri, rad[j], mi, mass[j], vxi - vx[j], vyi - vy[j],
                                   vzi - vz[j], ax, ay, az);
      }
      if (delta <= 0.0)
        return;
      // The ratio's divide only when it sets a new maximum (rare after the first contacts).
      const double rmin = std::min(ri, rad[j]);
      if (delta > max_ratio * rmin)
        max_ratio = delta / rmin;
      violations += delta > m.max_overlap * rmin;
    };
    // Pairs inside the box first (no periodic image needed), then those across a face.
    const std::uint32_t kw = Wrap ? wrap[i] : off[i];
    for (std::uint32_t k = off[i]; k < kw; ++k) {
      const std::uint32_t j = nb[k];
      if constexpr (Label) {
        if (label[j] != island)
          continue;
      }
      pair(k, j, x[j] - xi, y[j] - yi, z[j] - zi);
    }
    for (std::uint32_t k = kw; k < off[i + 1]; ++k) {
      const std::uint32_t j = nb[k];
      if constexpr (Label) {
        if (label[j] != island)
          continue;
      }
      pair(k, j, g.image(x[j] - xi, 0), g.image(y[j] - yi, 1), g.image(z[j] - zi, 2));
    }
    if (!(g.periodic[0] && g.periodic[1] && g.periodic[2]))
      add_member_walls<Friction, Cylinder>(v, i, ax, ay, az, wi, tq, max_ratio, violations);
    fxo[i] = ax, fyo[i] = ay, fzo[i] = az;
    if constexpr (Friction)
      v.c.tx[i] = tq[0], v.c.ty[i] = tq[1], v.c.tz[i] = tq[2];
  }
  max_ratio_out = max_ratio;
  violations_out += violations;
  return pairs;
}
template <bool Label, bool Indexed, bool Wrap, bool ById, bool Friction = false>
std::int64_t contact_forces(const ContactView& v, const std::uint32_t* idx, std::uint32_t u0,
                            std::uint32_t u1, std::uint32_t island, double& max_ratio_out,
                            std::int64_t& violations_out, double hk = 0.0) {
  return v.geom->cylinder ? contact_forces_of<Label, Indexed, Wrap, ById, Friction, true>(
                                v, idx, u0, u1, island, max_ratio_out, violations_out, hk)
                          : contact_forces_of<Label, Indexed, Wrap, ById, Friction, false>(
                                v, idx, u0, u1, island, max_ratio_out, violations_out, hk);
}

// The contact and wall forces of an island of two members i and j without friction (one rank;
// i the first in the island's member order): its one pair, a link (an island is connected),
// evaluated once; `across`: j lies in the part of i's row across a periodic face. The pass over
// both rows (contact_forces) evaluates it from each end, and j's contribution is bit for bit the
// negative of i's (every term changes sign, as in the explicit scheme's half list): this is that
// pass with half the pair work, and it tallies the overlaps as that pass does (the pair's from each
// end). Returns the pairs evaluated (1).
inline std::int64_t pair_island_forces(const ContactView& v, std::uint32_t i, std::uint32_t j,
                                       bool across, double& max_ratio, std::int64_t& violations) {
  const DomainGeometry& g = *v.geom;
  const StepModel& m = *v.model;
  const Columns& c = v.c;
  double dx = c.x[j] - c.x[i], dy = c.y[j] - c.y[i], dz = c.z[j] - c.z[i];
  if (across)
    dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
  double ax = 0.0, ay = 0.0, az = 0.0;
  const double delta =
      add_normal_contact(m, dx, dy, dz, c.radius[i], c.radius[j], c.mass[i], c.mass[j],
                         c.vx[i] - c.vx[j], c.vy[i] - c.vy[j], c.vz[i] - c.vz[j], ax, ay, az);
  double bx = 0.0 - ax, by = 0.0 - ay, bz = 0.0 - az; // j's end: 0 + (-contribution)
  // The tallies in the two rows' order: i's pair, i's walls, j's pair, j's walls.
  const double rmin = std::min(c.radius[i], c.radius[j]);
  auto tally_pair = [&] {
    if (delta <= 0.0)
      return;
    if (delta > max_ratio * rmin)
      max_ratio = delta / rmin;
    violations += delta > m.max_overlap * rmin;
  };
  const bool walls = !(g.periodic[0] && g.periodic[1] && g.periodic[2]);
  const double w[3] = {0.0, 0.0, 0.0};
  double tq[3] = {0.0, 0.0, 0.0};
  auto member_walls = [&](std::uint32_t k, double& fx, double& fy, double& fz) {
    if (!g.cylinder)
      add_member_walls<false>(v, k, fx, fy, fz, w, tq, max_ratio, violations);
    else
      add_member_walls<false, true>(v, k, fx, fy, fz, w, tq, max_ratio, violations);
  };
  tally_pair();
  if (walls)
    member_walls(i, ax, ay, az);
  tally_pair();
  if (walls)
    member_walls(j, bx, by, bz);
  c.fx[i] = ax, c.fy[i] = ay, c.fz[i] = az;
  c.fx[j] = bx, c.fy[j] = by, c.fz[j] = bz;
  return 1;
}

// What one island's fine steps add to the scheme's counters.
struct IslandResult {
  std::int64_t pairs = 0, violations = 0, bound_violations = 0;
  std::int64_t steps = 0; // member steps taken (K each, less the folded ones)
  // member steps less the leads' alone (what "auto" prices as fine work: the same on any rank
  // count, where islands spanning ranks fold no step after their lead)
  std::int64_t lead_steps = 0;
  double max_ratio = 0.0;
};

// The members of an island (particle indices) and their positions at the sub-iteration's start
// (member order). The displacement check after each step: farther than bound[i] x elapsed +
// margin counts as a bound violation (step_island<.., Bounded = true>); else (the R-rank dense
// mode) farther than sqrt(fixed2) (half the skin: the rows may miss a pair).
// lead: the island's leading fine steps that see no contact (entry_lead()); when it is 2 or more
// they are taken as one step. leads: one per member instead (members of several islands).
// Spans with lengths: mem, x0..z0 and leads by member, bound by particle (empty unless Bounded).
struct Members {
  std::span<const std::uint32_t> mem;
  std::span<const double> x0, y0, z0;
  std::span<const double> bound;
  double margin, fixed2;
  std::int64_t lead = 0;
  std::span<const std::int64_t> leads = {}; // per member, instead of `lead` (empty: `lead`)
  [[nodiscard]] std::uint32_t count() const { return static_cast<std::uint32_t>(mem.size()); }
};

// The entry time of island member i: none of its pairs in the island, nor a wall, can close
// before it while both ends fly free. Until a member's first contact nothing but gravity and its
// held force acts on it, so it stays within its own speed bound own[i] t of its start (the bound
// before the island raised it: the raise covers what contacts can pass on, which needs a contact
// first); a pair's gap, less the link test's margin, thus stays positive while
// t < (gap - margin) / (s_i + s_j), a wall gap while t < (gap - margin) / s_i (the link and tie
// tests' margin). 0 when a gap is already within the margin (an overlap), infinite for members
// at rest. The island's entry time is the least over its members: before it nothing in the
// island touches anything, and no contact can speed a member up. A pair that could close within
// the sub-iteration is linked, so every valid row set holds it: the time, capped at dt_sp, is the
// same for every list and rank count.
// pair(j, dx, dy, dz) for every partner j of particle i in island `island`, in row order, with
// the separation x_j - x_i (its image for the row's pairs across a periodic face; every pair's
// without Wrap, as on R ranks).
template <bool Wrap, class Pair>
[[gnu::always_inline]] inline void island_partners(const ContactView& v, std::uint32_t i,
                                                   std::uint32_t island, Pair&& pair) {
  const DomainGeometry& g = *v.geom;
  const double* __restrict x = v.c.x.data();
  const double* __restrict y = v.c.y.data();
  const double* __restrict z = v.c.z.data();
  const std::uint32_t* __restrict off = v.rows.off.data();
  const std::uint32_t* __restrict nb = v.rows.nb.data();
  const std::uint32_t kw = Wrap ? v.rows.wrap[i] : off[i];
  for (std::uint32_t k = off[i]; k < off[i + 1]; ++k) {
    const std::uint32_t j = nb[k];
    if (v.label[j] != island)
      continue;
    double dx = x[j] - x[i], dy = y[j] - y[i], dz = z[j] - z[i];
    if (k >= kw)
      dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
    pair(j, dx, dy, dz);
  }
}

// Cylinder: the curved wall's gap too (the callers choose once, outside their member loops).
template <bool Wrap, bool Cylinder>
double member_entry_time_of(const ContactView& v, const double* own, double margin,
                            std::uint32_t island, std::uint32_t i) {
  const DomainGeometry& g = *v.geom;
  const double* __restrict rad = v.c.radius.data();
  const double ri = rad[i], si = own[i];
  double t = std::numeric_limits<double>::infinity();
  island_partners<Wrap>(v, i, island, [&](std::uint32_t j, double dx, double dy, double dz) {
    const double gap = std::sqrt(dx * dx + dy * dy + dz * dz) - ri - rad[j] - margin;
    t = std::min(t, closing_time(gap, si + own[j]));
  });
  const double pos[3] = {v.c.x[i], v.c.y[i], v.c.z[i]};
  for (int a = 0; a < 3; ++a)
    if (!g.periodic[a])
      t = std::min(t, closing_time(wall_gap(pos[a], g.lo[a], g.hi[a], ri) - margin, si));
  if constexpr (Cylinder) // the curved wall's gap closes at most as fast as the particle moves
    t = std::min(t, closing_time(cylinder_gap(g, pos, ri) - margin, si));
  return t;
}
template <bool Wrap>
double member_entry_time(const ContactView& v, const double* own, double margin,
                         std::uint32_t island, std::uint32_t i) {
  return with_flags(
      [&](auto cyl) { return member_entry_time_of<Wrap, cyl>(v, own, margin, island, i); },
      v.geom->cylinder);
}
template <bool Wrap>
double entry_time(const ContactView& v, const Members& mb, const double* own,
                  std::uint32_t island) {
  return with_flags(
      [&](auto cyl) {
        constexpr bool Cylinder = decltype(cyl)::value;
        double t = std::numeric_limits<double>::infinity();
        for (std::uint32_t u = 0; u < mb.count(); ++u)
          t = std::min(t,
                       member_entry_time_of<Wrap, Cylinder>(v, own, mb.margin, island, mb.mem[u]));
        return t;
      },
      v.geom->cylinder);
}

// The first time a gap can close, from now, when it closes no faster than `rate` (negative when
// it closes) and its rate of closing grows by at most `accel` (>= 0): the positive root of
// gap + rate t - accel t^2 / 2, each form taken where it does not cancel; 0 when the gap is
// already closed, infinite when it never closes.
inline double free_span(double gap, double rate, double accel) {
  // Anything that is not a number gives 0: no step is taken on its word.
  if (!(gap > 0.0) || !(accel >= 0.0) || std::isnan(rate))
    return 0.0;
  const double inf = std::numeric_limits<double>::infinity();
  const double root = std::sqrt(rate * rate + 2.0 * accel * gap);
  if (rate > 0.0)
    return accel > 0.0 ? (rate + root) / accel : inf;
  const double den = root - rate;
  return den > 0.0 ? 2.0 * gap / den : inf; // den = 0: at rest, no acceleration
}

// How long the island's members keep flying free from the current fine step's node, at which no
// contact force acts on any of them: until then no pair of members in the island, nor a member
// and a wall, can touch. Free flight under gravity and the held force is a parabola, so the
// separation of a pair is d(t) = d + w t + Da t^2 / 2 (w: the velocities' difference at the node,
// the stored half-step ones brought to the node by hp; Da: the accelerations' difference), and
// |d(t)| >= d.d(t) / |d| = |d| + w_n t + (Da.d / |d|) t^2 / 2 >= |d| + w_n t - |Da| t^2 / 2: the
// gap, less the link test's margin, stays positive until free_span() of that. A wall gap is
// x - lo - r (or hi - x - r) on the same parabola. The leapfrog's nodes lie on the parabola up to
// rounding, which the margin covers. No particle outside the island can reach a member within the
// sub-iteration (the link test), so this is every contact the members can meet.
template <bool Wrap, bool External, bool Cylinder>
double free_time_of(const ContactView& v, const Members& mb, std::uint32_t island,
                    const std::array<double, 3>& grav) {
  const DomainGeometry& g = *v.geom;
  const Columns& c = v.c;
  // A particle's acceleration in free flight, and its velocity at the node.
  auto motion = [&](std::uint32_t i, double(&a)[3], double(&u)[3]) {
    a[0] = grav[0], a[1] = grav[1], a[2] = grav[2];
    if constexpr (External) {
      a[0] += c.ex[i] * c.im[i], a[1] += c.ey[i] * c.im[i], a[2] += c.ez[i] * c.im[i];
    }
    u[0] = c.vx[i] + a[0] * c.hp[i], u[1] = c.vy[i] + a[1] * c.hp[i];
    u[2] = c.vz[i] + a[2] * c.hp[i];
  };
  double t = std::numeric_limits<double>::infinity();
  for (std::uint32_t m = 0; m < mb.count(); ++m) {
    const std::uint32_t i = mb.mem[m];
    double ai[3], ui[3];
    motion(i, ai, ui);
    const double ri = c.radius[i];
    island_partners<Wrap>(v, i, island, [&](std::uint32_t j, double dx, double dy, double dz) {
      double aj[3], uj[3];
      motion(j, aj, uj);
      const double dist = std::sqrt(dx * dx + dy * dy + dz * dz);
      const double wn = ((uj[0] - ui[0]) * dx + (uj[1] - ui[1]) * dy + (uj[2] - ui[2]) * dz) / dist;
      const double da[3] = {aj[0] - ai[0], aj[1] - ai[1], aj[2] - ai[2]};
      const double accel = std::sqrt(da[0] * da[0] + da[1] * da[1] + da[2] * da[2]);
      t = std::min(t, free_span(dist - (ri + c.radius[j]) - mb.margin, wn, accel));
    });
    const double pos[3] = {c.x[i], c.y[i], c.z[i]};
    for (int a = 0; a < 3; ++a)
      if (!g.periodic[a]) {
        t = std::min(t, free_span(pos[a] - g.lo[a] - ri - mb.margin, ui[a], std::abs(ai[a])));
        t = std::min(t, free_span(g.hi[a] - pos[a] - ri - mb.margin, -ui[a], std::abs(ai[a])));
      }
    if constexpr (Cylinder) {
      // On the parabola rho(t) <= rho + |u_perp| t + |a_perp| t^2 / 2 (u_perp, a_perp: across
      // the axis), so the curved wall's gap R - r - rho(t) closes no sooner than this.
      const double up = std::hypot(ui[g.u], ui[g.w]), ap = std::hypot(ai[g.u], ai[g.w]);
      t = std::min(t, free_span(cylinder_gap(g, pos, ri) - mb.margin, -up, ap));
    }
  }
  return t;
}
// free_time_of with or without a cylinder's curved wall, chosen once per call.
template <bool Wrap, bool External>
double free_time(const ContactView& v, const Members& mb, std::uint32_t island,
                 const std::array<double, 3>& grav) {
  return v.geom->cylinder ? free_time_of<Wrap, External, true>(v, mb, island, grav)
                          : free_time_of<Wrap, External, false>(v, mb, island, grav);
}

// The leading fine steps taken as one step of lead x h (step_island): every force that step
// reads must be free of contact, at its start (t = 0) and at its end (t = lead h, where the
// velocity's closing half kick spans lead h / 2 instead of h / 2). So lead h < t_e:
// ceil(t_e / h) - 1; the whole sub-iteration (K) when t_e >= dt_sp, as a lone particle's single
// step of dt_sp.
inline std::int64_t entry_lead(double t_e, double dt_sp, const FineSteps& fs) {
  if (!(t_e > 0.0))
    return 0;
  if (t_e >= dt_sp)
    return fs.K;
  return std::min<std::int64_t>(fs.K, static_cast<std::int64_t>(std::ceil(t_e / fs.h)) - 1);
}

// step_island's free_time argument where no fold is taken after the leading steps.
struct NoFold {};

// Islands larger than this run each pass over blocks of members, the blocks given to the
// caller's `for_blocks(n, f)` (f(b) for every block b < n, in any order, on any thread: each
// block writes only its own partial counts, summed afterwards in block order). The caller owns
// the iteration: the schemes pass TBB tasks (dem/task_blocks.hpp), a test may pass SerialBlocks.
inline constexpr std::uint32_t kGiantIsland = 4096;
inline constexpr std::uint32_t kMemberBlock = 1024;

// for_blocks for callers that run every block on the calling thread, in order.
struct SerialBlocks {
  template <class F> void operator()(std::size_t n, F&& f) const {
    for (std::size_t b = 0; b < n; ++b)
      f(b);
  }
};

// The K fine steps of an island (fine_steps(): h, the last one h_last) with the orb scheme's
// variable-step leapfrog (h_prev per particle): contact forces from `forces(u0, u1, max_ratio,
// violations)` over members u0..u1 (returns the pairs), then every member's kick-drift, then
// `between()` before every step but the first (the R-rank ghost refresh); a giant island's
// blocks of members through `for_blocks` (above). With svx non-null the
// synchronised velocities at the start go there. Each member's force and update read only the
// state before the pass: bitwise independent of the thread count.
//
// With free_time() (one lead for all members, between() doing nothing): at a node where no
// contact force acts on any member, free_time() says how long the island flies free from it
// (islands::free_time), and the fine steps that end before then are one step, as the leading
// ones are, up to the sub-iteration's last step, which stays a fine one (so every member ends
// with the fine half step, and the next sub-iteration's forces close it as they would without
// the fold). It is asked again once a contact has come and gone, or once its last answer has
// passed without a contact (a pair that closed in on its line of centres and missed).
template <bool External, bool Bounded, bool Friction = false, class Forces, class Between,
          class ForBlocks, class FreeTime = NoFold>
[[gnu::always_inline]] inline IslandResult
step_island(const Columns& col, const Members& mb, const FineSteps& fs,
            const std::array<double, 3>& grav, double* svx, double* svy, double* svz,
            Forces&& forces, Between&& between, ForBlocks&& for_blocks,
            FreeTime&& free_time = FreeTime{}) {
  constexpr bool kFolds = !std::is_same_v<std::decay_t<FreeTime>, NoFold>;
  IslandResult res;
  const std::uint32_t* mem = mb.mem.data();
  const std::uint32_t count = mb.count();
  double* x = col.x.data();
  double* y = col.y.data();
  double* z = col.z.data();
  double* vx = col.vx.data();
  double* vy = col.vy.data();
  double* vz = col.vz.data();
  double* fx = col.fx.data();
  double* fy = col.fy.data();
  double* fz = col.fz.data();
  double* hp = col.hp.data();
  const double* im = col.im.data();
  // Member u's update over one step. Everything it reads besides the particle's own state is
  // held in locals (the stores through x, v, hp could alias the views otherwise, and the
  // compiler would reload them for every member).
  const double* __restrict x0 = mb.x0.data();
  const double* __restrict y0 = mb.y0.data();
  const double* __restrict z0 = mb.z0.data();
  const double* __restrict bnd = mb.bound.data();
  const double* __restrict ex_x = col.ex.data();
  const double* __restrict ex_y = col.ey.data();
  const double* __restrict ex_z = col.ez.data();
  const double g0 = grav[0], g1 = grav[1], g2 = grav[2], margin = mb.margin, fixed2 = mb.fixed2;
  [[maybe_unused]] double* wx = col.wx.data();
  [[maybe_unused]] double* wy = col.wy.data();
  [[maybe_unused]] double* wz = col.wz.data();
  [[maybe_unused]] const double* tx = col.tx.data();
  [[maybe_unused]] const double* ty = col.ty.data();
  [[maybe_unused]] const double* tz = col.tz.data();
  [[maybe_unused]] const double* ii = col.ii.data();
  auto kick = [=](std::uint32_t u, double s, double hk, double half, double elapsed,
                  std::int64_t& bound_violations) {
    const std::uint32_t i = mem[u];
    double ex = 0.0, ey = 0.0, ez = 0.0;
    if constexpr (External)
      ex = ex_x[i], ey = ex_y[i], ez = ex_z[i];
    const double ims = im[i] * s;
    double px = x[i], py = y[i], pz = z[i], ux = vx[i], uy = vy[i], uz = vz[i];
    kick_drift(px, ux, fx[i] + ex, ims, g0 * s, hk);
    kick_drift(py, uy, fy[i] + ey, ims, g1 * s, hk);
    kick_drift(pz, uz, fz[i] + ez, ims, g2 * s, hk);
    x[i] = px, y[i] = py, z[i] = pz, vx[i] = ux, vy[i] = uy, vz[i] = uz;
    hp[i] = half;
    if constexpr (Friction) {
      // The spin's kick over the same span s (the explicit scheme's w += T (1/I) dt).
      const double si = ii[i] * s;
      wx[i] += tx[i] * si, wy[i] += ty[i] * si, wz[i] += tz[i] * si;
    }
    const double dx = px - x0[u], dy = py - y0[u], dz = pz - z0[u];
    if constexpr (Bounded) {
      const double reach = bnd[i] * elapsed + margin;
      bound_violations += dx * dx + dy * dy + dz * dz > reach * reach;
    } else {
      bound_violations += dx * dx + dy * dy + dz * dz > fixed2;
    }
  };
  const bool giant = count > kGiantIsland;
  // A giant island's passes run over blocks of members (for_blocks); each block's partial
  // counts go here (one allocation per sub-iteration, not per step).
  std::vector<IslandResult> parts(giant ? (count + kMemberBlock - 1) / kMemberBlock : 0);
  auto block_end = [&](std::size_t b) {
    return std::min<std::uint32_t>(count, static_cast<std::uint32_t>((b + 1) * kMemberBlock));
  };
  // A member's first `lead` steps (lead >= 2) are one step of lead x h: it touches nothing before
  // its island's entry time, so those steps see no contact force on it, and one variable-step
  // leapfrog step under the constant acceleration is their free flight (the same positions and
  // velocities up to rounding, as the free-flight kernel's single step of dt_sp for a lone
  // particle). Its steps skip .. K - 1 remain, the first lengthened. One lead for all members
  // (mb.leads empty) keeps the passes over member ranges; leads per member (the R-rank spanning
  // members: several islands in one call) evaluate each member from its own first step on. A
  // member's kick reads its own last half step (hp), the common one's when all step together.
  const std::int64_t K = fs.K;
  auto skip_of = [&](std::uint32_t u) {
    return std::clamp<std::int64_t>(!mb.leads.empty() ? mb.leads[u] : mb.lead, 1, K) - 1;
  };
  // Per-member leads run every step: between() is collective there (the R-rank ghost refresh),
  // so every rank calls it K - 1 times whatever its members' leads.
  const bool uniform = mb.leads.empty();
  const std::int64_t k0 = uniform && count > 0 ? skip_of(0) : 0;
  double elapsed = static_cast<double>(k0) * fs.h;
  std::int64_t taken = 0; // steps every member took (one lead)
  double ask_at = 0.0;    // free_time() is asked at contact-free nodes from this time on
  for (std::int64_t k = k0; k < K; ++k) {
    double base = k + 1 == K ? fs.h_last : fs.h;
    // The length of this step for a member whose steps start at s (<= k).
    auto length = [&](std::int64_t s) {
      return base + (k == s ? static_cast<double>(s) * fs.h : 0.0);
    };
    if (k > k0)
      between();
    // With friction the springs advance over the step: the forces take its length.
    auto evaluate = [&](std::uint32_t u0, std::uint32_t u1, double& max_ratio,
                        std::int64_t& violations, [[maybe_unused]] double hk) {
      if constexpr (Friction)
        return forces(u0, u1, max_ratio, violations, hk);
      else
        return forces(u0, u1, max_ratio, violations);
    };
    // The forces on members u0 .. u1 that step now.
    auto evaluate_range = [&](std::uint32_t u0, std::uint32_t u1, IslandResult& r) {
      if (uniform) {
        r.pairs += evaluate(u0, u1, r.max_ratio, r.violations, length(k0));
        return;
      }
      for (std::uint32_t u = u0; u < u1; ++u)
        if (const std::int64_t s = skip_of(u); s <= k)
          r.pairs += evaluate(u, u + 1, r.max_ratio, r.violations, length(s));
    };
    if (!giant) {
      evaluate_range(0u, count, res);
    } else {
      for_blocks(parts.size(), [&](std::size_t b) {
        IslandResult& pt = parts[b];
        pt = IslandResult{};
        evaluate_range(static_cast<std::uint32_t>(b * kMemberBlock),
                       static_cast<std::uint32_t>(block_end(b)), pt);
      });
      for (const IslandResult& pt : parts)
        res.pairs += pt.pairs, res.violations += pt.violations,
            res.max_ratio = std::max(res.max_ratio, pt.max_ratio);
    }
    if (svx != nullptr)
      for (std::uint32_t u = 0; u < count; ++u) {
        if (skip_of(u) != k)
          continue;
        const std::uint32_t i = mem[u];
        double ex = 0.0, ey = 0.0, ez = 0.0;
        if constexpr (External)
          ex = ex_x[i], ey = ex_y[i], ez = ex_z[i];
        svx[i] = vx[i] + ((fx[i] + ex) * im[i] + g0) * hp[i];
        svy[i] = vy[i] + ((fy[i] + ey) * im[i] + g1) * hp[i];
        svz[i] = vz[i] + ((fz[i] + ez) * im[i] + g2) * hp[i];
      }
    // Fold the steps k .. k + span - 1 into this one where the island flies free through them
    // and at the node that ends them (its force closes the step's second half kick).
    std::int64_t span = 1;
    if constexpr (kFolds) {
      bool flying = uniform;
      for (std::uint32_t u = 0; flying && u < count; ++u) {
        const std::uint32_t i = mem[u];
        flying = fx[i] == 0.0 && fy[i] == 0.0 && fz[i] == 0.0;
      }
      // The node is at the sub-iteration's start when this step also takes the lead's steps.
      const double lead = k == k0 ? static_cast<double>(k0) * fs.h : 0.0;
      const double node = elapsed - lead;
      if (!flying) {
        ask_at = 0.0;
      } else if (node >= ask_at) {
        const double t_free = free_time();
        ask_at = node + t_free;
        // The steps k .. k + L - 1 as one, and the step's length from the node (with the lead's
        // steps when this is the first).
        auto fold_length = [&](std::int64_t L) {
          return static_cast<double>(L - 1) * fs.h + (k + L == K ? fs.h_last : fs.h);
        };
        auto span_length = [&](std::int64_t L) { return lead + fold_length(L); };
        std::int64_t L = K - 1 - k;
        if (L >= 2 && !(span_length(L) < t_free)) {
          L = std::min<std::int64_t>(
              L, static_cast<std::int64_t>(std::ceil((t_free - lead) / fs.h)) - 1);
          while (L >= 2 && !(span_length(L) < t_free))
            --L;
        }
        if (L >= 2)
          span = L, base = fold_length(L);
      }
    }
    ++taken;
    elapsed += base;
    auto kick_range = [&](std::uint32_t u0, std::uint32_t u1, std::int64_t& bv) {
      for (std::uint32_t u = u0; u < u1; ++u) {
        const std::int64_t s = skip_of(u);
        if (s > k)
          continue;
        const double hk = length(s), half = 0.5 * hk;
        kick(u, hp[mem[u]] + half, hk, half, elapsed, bv);
      }
    };
    if (!giant) {
      kick_range(0u, count, res.bound_violations);
    } else {
      for_blocks(parts.size(), [&](std::size_t b) {
        std::int64_t& bv = parts[b].bound_violations;
        bv = 0;
        kick_range(static_cast<std::uint32_t>(b * kMemberBlock),
                   static_cast<std::uint32_t>(block_end(b)), bv);
      });
      for (const IslandResult& pt : parts)
        res.bound_violations += pt.bound_violations;
    }
    k += span - 1;
  }
  for (std::uint32_t u = 0; u < count; ++u)
    res.lead_steps += K - skip_of(u);
  res.steps = uniform ? static_cast<std::int64_t>(count) * taken : res.lead_steps;
  return res;
}

// The free-flight kernel over len particles (pointers at the run's first): one step of dt under
// gravity and the held force, no contact. Branch-free, so that it vectorizes: a coordinate or
// speed that is not finite makes q - q a NaN (non-zero bits), and a particle beyond a wall makes
// the smallest of its wall gaps negative (sign bit; with Walls only: on a periodic axis the
// bounds are infinite). Returns a value with the sign bit set when either happened. (Positional
// restrict parameters: GCC vectorizes this loop only with them.)
template <bool External, bool Record, bool Walls>
std::uint64_t
free_flight_kernel(double* __restrict x, double* __restrict y, double* __restrict z,
                   double* __restrict vx, double* __restrict vy, double* __restrict vz,
                   double* __restrict hp, const double* __restrict im, const double* __restrict ex,
                   const double* __restrict ey, const double* __restrict ez, double* __restrict sx,
                   double* __restrict sy, double* __restrict sz, std::size_t len, const double* g,
                   double dt, const WallBounds& wb) {
  const double g0 = g[0], g1 = g[1], g2 = g[2], half = 0.5 * dt;
  const double lo0 = wb.lo[0], lo1 = wb.lo[1], lo2 = wb.lo[2];
  const double hi0 = wb.hi[0], hi1 = wb.hi[1], hi2 = wb.hi[2];
  std::uint64_t nonfinite = 0, outside = 0;
  for (std::size_t i = 0; i < len; ++i) {
    double ax = g0, ay = g1, az = g2;
    if constexpr (External) {
      ax += ex[i] * im[i], ay += ey[i] * im[i], az += ez[i] * im[i];
    }
    if constexpr (Record) {
      sx[i] = vx[i] + ax * hp[i], sy[i] = vy[i] + ay * hp[i], sz[i] = vz[i] + az * hp[i];
    }
    const double s = hp[i] + half;
    double px = x[i], py = y[i], pz = z[i], ux = vx[i], uy = vy[i], uz = vz[i];
    kick_drift(px, ux, 0.0, 0.0, ax * s, dt);
    kick_drift(py, uy, 0.0, 0.0, ay * s, dt);
    kick_drift(pz, uz, 0.0, 0.0, az * s, dt);
    x[i] = px, y[i] = py, z[i] = pz, vx[i] = ux, vy[i] = uy, vz[i] = uz;
    hp[i] = half;
    const double q = ux * ux + uy * uy + uz * uz + px + py + pz;
    nonfinite |= std::bit_cast<std::uint64_t>(q - q); // 0 when q is finite
    if constexpr (Walls) {
      // x - lo and hi - x are +0 at a wall, negative beyond it (q catches a NaN coordinate).
      const double gx = std::min(px - lo0, hi0 - px), gy = std::min(py - lo1, hi1 - py);
      const double gap = std::min(std::min(gx, gy), std::min(pz - lo2, hi2 - pz));
      outside |= std::bit_cast<std::uint64_t>(gap);
    }
  }
  return (nonfinite != 0 ? std::uint64_t{1} << 63 : 0) | (outside & (std::uint64_t{1} << 63));
}

// free_flight_kernel over the particles [b, e) of the columns c, the view the schemes hold; with
// Record the synchronised velocities go to sv (the store's length). The kernel keeps its
// positional restrict parameters: GCC vectorizes the loop only with them.
template <bool External, bool Record, bool Walls>
std::uint64_t free_flight(const Columns& c, std::size_t b, std::size_t e,
                          const std::array<std::span<double>, 3>& sv,
                          const std::array<double, 3>& g, double dt, const WallBounds& wb) {
  return free_flight_kernel<External, Record, Walls>(
      c.x.data() + b, c.y.data() + b, c.z.data() + b, c.vx.data() + b, c.vy.data() + b,
      c.vz.data() + b, c.hp.data() + b, c.im.data() + b, External ? c.ex.data() + b : nullptr,
      External ? c.ey.data() + b : nullptr, External ? c.ez.data() + b : nullptr,
      Record ? sv[0].data() + b : nullptr, Record ? sv[1].data() + b : nullptr,
      Record ? sv[2].data() + b : nullptr, e - b, g.data(), dt, wb);
}

// A particle whose position or velocity is not finite, or which is outside a wall.
struct Fault {
  std::size_t index = 0;
  bool nonfinite = false;
};
// The first faulty particle of [0, n), if any. Faults are rare: a branch-free pass (it
// vectorizes) says whether to look for one.
std::optional<Fault> find_fault(const ParticleStore& p, std::size_t n, const DomainGeometry& g);
// "t = .. s, sub-iteration ..: particle <id> at (..) m: <what>" (the run's stop message).
std::string fault_message(const ParticleStore& p, const Fault& f, double t, std::int64_t subit,
                          const StepModel& m);

} // namespace cfddem::dem::islands
