// The passes of one velocity Verlet step over a Verlet list, of the explicit scheme on any rank
// count (dem/explicit_scheme.hpp), so one rank and R ranks take the same floating-point path: the
// contact pass over the list's rows, wall forces, the vectorized kick-drift of a range, and the
// search and wording of a failed check. Loops over spans of the store: no allocation, no MPI; the
// contact pass hands rows to TBB with a fixed partition.
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/partitioner.h>

#include "core/particle_store.hpp"
#include "dem/contact_kernels.hpp"
#include "dem/contact_scatter.hpp"
#include "dem/domain_geometry.hpp"
#include "dem/external_force.hpp"
#include "dem/flag_dispatch.hpp"
#include "dem/friction_kernels.hpp"
#include "dem/kick_drift_range.hpp"
#include "dem/linear_spring_dashpot.hpp"
#include "dem/pair_contacts.hpp"
#include "dem/pair_stream.hpp"
#include "dem/particle_views.hpp"
#include "dem/step_model.hpp"
#include "dem/step_report.hpp"
#include "dem/travel_bound.hpp"
#include "dem/verlet_list.hpp"

namespace cfddem::dem {

// Rows per block of the pair pass: blocks are fixed by position in the row list, so the contacts
// and their order do not depend on the thread count.
inline constexpr std::size_t kPairBlock = 256;
// Blocks with at least this many pairs find their touching pairs in a pass of their own.
inline constexpr std::uint32_t kTwoPassPairs = 128;

// The pairs of one PairStream (Tail = false: the rows' parts before wrap_begin(), whose raw
// separations are the minimum image; Tail = true: the parts from wrap_begin(), through `geom`'s
// periodic image): the contacts, into one PairContacts per block of the stream. Overlaps beyond
// the bound are flagged on i (the lower index, as a full list's first flag would be).
// `history`: tangential history per list entry (friction only; the stream holds the entries),
// zeroed for pairs apart. Returns the number of blocks written (the first ones of `blocks`).
// Tally: also count every overlap beyond the bound and the largest overlap ratio into `out`
// (the islands scheme's global steps count overlaps where the explicit scheme stops).
template <bool Friction, bool Tail, bool Tally = false>
std::size_t pair_pass(const ParticleStore& p, const PairStream& stream,
                      [[maybe_unused]] HistoryColumns history, const DomainGeometry& geom,
                      const StepModel& model, double dt, std::vector<PairContacts>& blocks,
                      StepReport& out) {
  [[maybe_unused]] double* hx = history.x.data();
  [[maybe_unused]] double* hy = history.y.data();
  [[maybe_unused]] double* hz = history.z.data();
  const double* __restrict x = p.x.data();
  const double* __restrict y = p.y.data();
  const double* __restrict z = p.z.data();
  const double* __restrict vx = p.vx.data();
  const double* __restrict vy = p.vy.data();
  const double* __restrict vz = p.vz.data();
  const double* __restrict rad = p.radius.data();
  const double* __restrict mass = p.mass.data();
  [[maybe_unused]] const double* __restrict wx = p.wx.data();
  [[maybe_unused]] const double* __restrict wy = p.wy.data();
  [[maybe_unused]] const double* __restrict wz = p.wz.data();
  const std::uint32_t* __restrict si = stream.i.data();
  const std::uint32_t* __restrict sj = stream.j.data();
  [[maybe_unused]] const std::uint32_t* __restrict sk = stream.k.data();
  const std::uint32_t* __restrict start = stream.block_start.data();
  const DomainGeometry g = geom;
  const StepModel m = model;
  const std::size_t nblocks = stream.blocks();
  if (blocks.size() < nblocks)
    blocks.resize(nblocks);

  // Equal radii (the common case): the contact distance r_i + r_j is this constant, bit for bit.
  const double rs_uniform = m.r_min + m.r_min;
  auto blocks_of = [&]<bool Uniform>(const tbb::blocked_range<std::size_t>& r, StepReport rep) {
    for (std::size_t b = r.begin(); b != r.end(); ++b) {
      PairContacts& c = blocks[b];
      c.size = 0;
      const std::uint32_t e0 = start[b], e1 = start[b + 1];
      c.reserve_more(e1 - e0, Friction);
      std::uint32_t* __restrict ci = c.i.data();
      std::uint32_t* __restrict cj = c.j.data();
      double* __restrict cax = c.ax.data();
      double* __restrict cay = c.ay.data();
      double* __restrict caz = c.az.data();
      // The separation of stream pair e (x_j - x_i, through the periodic image for the tail).
      auto separation = [&](std::uint32_t e, double& dx, double& dy, double& dz) {
        const std::uint32_t i = si[e], j = sj[e];
        dx = x[j] - x[i], dy = y[j] - y[i], dz = z[j] - z[i];
        if constexpr (Tail)
          dx = g.image(dx, 0), dy = g.image(dy, 1), dz = g.image(dz, 2);
      };
      auto contact_distance = [&](std::uint32_t e) {
        return Uniform ? rs_uniform : rad[si[e]] + rad[sj[e]];
      };
      // Contact t of the block from stream pair e, which touches.
      auto contact_at = [&](std::uint32_t e, std::size_t t) {
        const std::uint32_t i = si[e], j = sj[e];
        double dx, dy, dz;
        separation(e, dx, dy, dz);
        const double r2 = dx * dx + dy * dy + dz * dz;
        const double rs = contact_distance(e);
        // The same operations as a full list's row of i: each value here is, bit for bit,
        // the negative of what j's row computes (x_i - x_j == -(x_j - x_i) exactly).
        const double dist = std::sqrt(r2);
        const double inv = 1.0 / dist;
        const double nx = dx * inv, ny = dy * inv, nz = dz * inv;
        const double delta = rs - dist;
        const double dvx = vx[i] - vx[j], dvy = vy[i] - vy[j], dvz = vz[i] - vz[j];
        const double vn = dvx * nx + dvy * ny + dvz * nz;
        // Equal masses (the common case) skip the divide and square root of m_eff.
        const double meff = contact_meff(m, mass[i], mass[j]);
        const double fn = contact_normal_force(m, meff, delta, vn);
        ci[t] = i, cj[t] = j;
        cax[t] = fn * nx, cay[t] = fn * ny, caz[t] = fn * nz;
        const double rmin = std::min(rad[i], rad[j]);
        if (delta > m.max_overlap * rmin)
          rep.flag(i, StepFault::overlap, delta / rmin, j);
        if constexpr (Tally) {
          if (delta > rep.max_ratio * rmin)
            rep.max_ratio = delta / rmin;
          rep.overlaps += delta > m.max_overlap * rmin;
        }
        if constexpr (Friction) {
          const std::uint32_t k = sk[e];
          // Contact-point relative velocity: v_i - v_j + (r_i w_i + r_j w_j) x n
          // (docs/theory.md §2).
          const double sx = rad[i] * wx[i] + rad[j] * wx[j];
          const double sy = rad[i] * wy[i] + rad[j] * wy[j];
          const double sz = rad[i] * wz[i] + rad[j] * wz[j];
          const double rvx = dvx + (sy * nz - sz * ny), rvy = dvy + (sz * nx - sx * nz),
                       rvz = dvz + (sx * ny - sy * nx);
          const double rvn = rvx * nx + rvy * ny + rvz * nz;
          const double nvec[3] = {nx, ny, nz};
          const double vt[3] = {rvx - rvn * nx, rvy - rvn * ny, rvz - rvn * nz};
          double xi3[3] = {hx[k], hy[k], hz[k]}, ft[3];
          tangential_force(m.pair_t, meff, dt, std::abs(fn), nvec, vt, xi3, ft);
          hx[k] = xi3[0], hy[k] = xi3[1], hz[k] = xi3[2];
          c.bx[t] = ft[0], c.by[t] = ft[1], c.bz[t] = ft[2];
          c.cx[t] = ny * ft[2] - nz * ft[1];
          c.cy[t] = nz * ft[0] - nx * ft[2];
          c.cz[t] = nx * ft[1] - ny * ft[0];
        }
      };
      const std::uint32_t np = e1 - e0;
      std::size_t s = 0;
      if (np >= kTwoPassPairs) {
        // Long blocks (a dense or large gas, whose coordinates stream from beyond L1): first
        // which pairs touch, with no branch (their stream positions packed, in order, into cj,
        // which the forces then overwrite), then the forces of those. The short loop without
        // the contact arithmetic keeps more loads in flight: measured 8% off the dense 100k
        // peer run, but slower on short blocks (HCS 1222), which take the one loop below.
        for (std::uint32_t e = e0; e < e1; ++e) {
          double dx, dy, dz;
          separation(e, dx, dy, dz);
          const double r2 = dx * dx + dy * dy + dz * dz, rs = contact_distance(e);
          const bool touch = !(r2 >= rs * rs); // a NaN separation counts as a contact
          cj[s] = e;
          s += touch ? 1 : 0;
          if constexpr (Friction) {
            const std::uint32_t k = sk[e];
            hx[k] = touch ? hx[k] : 0.0, hy[k] = touch ? hy[k] : 0.0, hz[k] = touch ? hz[k] : 0.0;
          }
        }
        for (std::size_t t = 0; t < s; ++t)
          contact_at(cj[t], t);
      } else {
        for (std::uint32_t e = e0; e < e1; ++e) {
          double dx, dy, dz;
          separation(e, dx, dy, dz);
          const double r2 = dx * dx + dy * dy + dz * dz, rs = contact_distance(e);
          if (r2 >= rs * rs) {
            if constexpr (Friction)
              hx[sk[e]] = hy[sk[e]] = hz[sk[e]] = 0.0;
            continue;
          }
          contact_at(e, s++);
        }
      }
      c.size = s;
      c.bound_indices();
    }
    return rep;
  };
  auto body = [&](const tbb::blocked_range<std::size_t>& r, StepReport rep) {
    return m.uniform_radius ? blocks_of.template operator()<true>(r, rep)
                            : blocks_of.template operator()<false>(r, rep);
  };
  const tbb::blocked_range<std::size_t> all(0, nblocks, 1);
  if (nblocks <= 4) {
    out.join(body(all, StepReport{})); // small work: no task overhead
  } else {
    out.join(tbb::parallel_reduce(
        all, StepReport{}, body,
        [](StepReport a, const StepReport& b) {
          a.join(b);
          return a;
        },
        tbb::simple_partitioner{}));
  }
  return nblocks;
}

// Planar walls at lo and hi of every non-periodic axis: force (and torque, with friction) added
// to particle i's contact force. Outward wall normal s = -1 at lo, +1 at hi. With Cylinder also
// the column's curved wall (dem/cylinder_wall.hpp).
template <bool Friction, bool Cylinder = false>
void add_wall_forces(const DomainGeometry& g, const StepModel& m, ParticleStore& p, std::size_t i,
                     double f[3], double tq[3], auto&& flag) {
  const double pos[3] = {p.x[i], p.y[i], p.z[i]}, vel[3] = {p.vx[i], p.vy[i], p.vz[i]};
  const double ri = p.radius[i], mi = p.mass[i];
  add_wall_contacts<Friction, Cylinder>(
      g, m.wall, m.wall_t, pos, vel, ri, [&] { return mi; },
      [&](double w[3]) { w[0] = p.wx[i], w[1] = p.wy[i], w[2] = p.wz[i]; }, f, tq,
      [&](double delta) {
        if (delta > m.max_overlap * ri)
          flag(delta / ri);
      });
}

// The particles of [0, n), increasing, that can touch a wall (a face of a non-periodic axis)
// before the list is next built: a particle moves at most skin/2 from its reference position
// (list.x_ref...) between builds, and touches a wall only within its radius of it, so those
// whose reference lies farther than radius + skin from every wall (a margin of a full skin, so
// that no rounding can matter) cannot, and the update pass skips their wall test. With a
// cylinder, those within radius + skin of the curved wall too (its gap R - rho - r shrinks by at
// most the distance moved).
// `ref`: the reference positions (x, y, z) of the build.
inline void near_walls(const ParticleStore& p, std::size_t n,
                       const std::array<std::span<const double>, 3>& ref, const DomainGeometry& g,
                       double skin, std::vector<std::uint32_t>& out) {
  out.clear();
  with_flags(
      [&](auto cyl) {
        constexpr bool Cylinder = decltype(cyl)::value;
        for (std::size_t i = 0; i < n; ++i) {
          const double reach = p.radius[i] + skin;
          bool near = false;
          for (int a = 0; a < 3; ++a)
            near = near || (!g.periodic[a] &&
                            !(ref[a][i] - g.lo[a] >= reach && g.hi[a] - ref[a][i] >= reach));
          if constexpr (Cylinder)
            near = near || !(cylinder_gap(g, ref[0][i], ref[1][i], ref[2][i], p.radius[i]) >= skin);
          if (near)
            out.push_back(static_cast<std::uint32_t>(i));
        }
      },
      g.cylinder);
}

inline void near_walls(const ParticleStore& p, std::size_t n, const VerletList& list,
                       const DomainGeometry& g, double skin, std::vector<std::uint32_t>& out) {
  near_walls(p, n, {list.x_ref(), list.y_ref(), list.z_ref()}, g, skin, out);
}

// Flags particle i in `out` if its position or velocity is not finite, or it is too fast (moves
// more than r_min per step: vmax2 = (r_min/dt)^2); whether it did.
inline bool flag_unfollowable(const ParticleStore& p, std::size_t i, double vmax2,
                              StepReport& out) {
  const double u2 = p.vx[i] * p.vx[i] + p.vy[i] * p.vy[i] + p.vz[i] * p.vz[i];
  if (u2 <= vmax2 && std::isfinite(p.x[i] + p.y[i] + p.z[i]))
    return false; // the common case: one test
  const auto ii = static_cast<std::uint32_t>(i);
  // A finite velocity whose square overflows (1e300 m/s) is a speed, not a NaN.
  const bool finite_v = std::isfinite(p.vx[i]) && std::isfinite(p.vy[i]) && std::isfinite(p.vz[i]);
  if (!finite_v || !std::isfinite(p.x[i] + p.y[i] + p.z[i]))
    out.flag(ii, StepFault::nan, u2);
  else
    out.flag(ii, StepFault::speed, std::hypot(p.vx[i], p.vy[i], p.vz[i]));
  return true;
}

// Rare path of the update: the first particle of [0, n) that is not finite, too fast
// (flag_unfollowable) or outside a wall, into `out`.
inline void find_fault(const ParticleStore& p, std::size_t n, const DomainGeometry& g, double vmax2,
                       StepReport& out) {
  for (std::size_t i = 0; i < n; ++i) {
    const double q[3] = {p.x[i], p.y[i], p.z[i]};
    const auto ii = static_cast<std::uint32_t>(i);
    if (!flag_unfollowable(p, i, vmax2, out)) {
      for (int a = 0; a < 3; ++a)
        if (!g.periodic[a] && !(q[a] >= g.lo[a] && q[a] <= g.hi[a]))
          out.flag(ii, StepFault::left_domain, q[a]);
      // Through the curved wall: the centre beyond R (the value names its axis coordinate u).
      if (g.cylinder && out.bad == kNoParticle && !(cylinder_gap(g, q, 0.0) >= 0.0))
        out.flag(ii, StepFault::left_domain, q[g.u]);
    }
    if (out.bad != kNoParticle)
      break;
  }
}

// v(n+1/2) = v(n-1/2) + (F/m + g) dt, x(n+1) = x(n) + v(n+1/2) dt over particles [0, n) (the
// store may hold more: ghost copies, which their owners update). Without
// walls the loop has no branch and vectorizes; the checks are folded into reductions and the
// offending particle is searched for only when one fails. `travel` (TravelBound) says whether
// the displacement test can be left out.
template <bool Walls, bool Friction, bool External>
void update_pass(ParticleStore& p, std::size_t n, const VerletList& list,
                 std::span<const std::uint32_t> near_wall, const ExternalForce& ext,
                 const DomainGeometry& geom, const StepModel& model, double dt, StepReport& out,
                 TravelBound& travel) {
  const DomainGeometry g = geom;
  const StepModel m = model;
  const double vmax2 = dt > 0 ? (m.r_min / dt) * (m.r_min / dt) : INFINITY;
  KickDriftStep step;
  step.s = dt, step.h = dt, step.g = m.gravity;
  step.half_skin2 = 0.25 * m.skin * m.skin, step.vmax2 = vmax2;
  // With walls the kick-drift also checks that every particle stays inside the box's walls.
  for (int a = 0; a < 3; ++a)
    if (!g.periodic[a])
      step.lo[a] = g.lo[a], step.hi[a] = g.hi[a];
  const KickDriftColumns columns =
      kick_drift_columns(p, list.x_ref(), list.y_ref(), list.z_ref(), External ? &ext : nullptr);
  // Leave the displacement test out while no particle can have moved skin/2 (TravelBound).
  const bool exact = !travel.may_skip(g, m.skin, dt);
  step.cap2 = travel.cap * travel.cap;

  struct Partial {
    std::int64_t moved = 0; // particles now farther than skin/2 from their build position
    std::int64_t failures = 0;
    bool over_cap = false; // without the exact test: some new |v| passed the cap
    StepReport walls;
  };
  auto body = [&](const tbb::blocked_range<std::size_t>& r, Partial acc) {
    if constexpr (Walls) {
      // Only particles near a wall (near_walls()). Their f (and t) holds this step's contact
      // force alone: the contact pass cleared it, with the last step's wall force, before adding
      // the contacts (ExplicitScheme::contact_pairs).
      double* __restrict fx = p.fx.data();
      double* __restrict fy = p.fy.data();
      double* __restrict fz = p.fz.data();
      const std::span<const std::uint32_t> near = listed_in(near_wall, r.begin(), r.end());
      with_flags(
          [&](auto cyl) {
            constexpr bool Cylinder = decltype(cyl)::value;
            for (const std::size_t i : near) {
              double f[3] = {fx[i], fy[i], fz[i]};
              double tq[3] = {0, 0, 0};
              if constexpr (Friction)
                tq[0] = p.tx[i], tq[1] = p.ty[i], tq[2] = p.tz[i];
              add_wall_forces<Friction, Cylinder>(g, m, p, i, f, tq, [&](double v) {
                acc.walls.flag(static_cast<std::uint32_t>(i), StepFault::overlap, v);
              });
              fx[i] = f[0], fy[i] = f[1], fz[i] = f[2];
              if constexpr (Friction)
                p.tx[i] = tq[0], p.ty[i] = tq[1], p.tz[i] = tq[2];
            }
          },
          g.cylinder);
    }
    KickDriftFlags flags;
    if (exact)
      kick_drift_range<External, false, true, true, Walls>(columns.range(r.begin(), r.end()), step,
                                                           flags);
    else
      kick_drift_range<External, false, true, false, Walls>(columns.range(r.begin(), r.end()), step,
                                                            flags);
    acc.over_cap = acc.over_cap || flags.over_cap();
    // A double: int64 counts of double compares do not vectorize on baseline x86-64.
    double fails = flags.too_fast() || flags.left_box() ? 1.0 : 0.0;
    if constexpr (Friction) {
      for (std::size_t i = r.begin(); i != r.end(); ++i) {
        const double s = p.inv_inertia[i] * dt;
        p.wx[i] += p.tx[i] * s, p.wy[i] += p.ty[i] * s, p.wz[i] += p.tz[i] * s;
      }
    }
    if constexpr (Walls) {
      if (g.cylinder) {
        const double* __restrict x = p.x.data();
        const double* __restrict y = p.y.data();
        const double* __restrict z = p.z.data();
        for (std::size_t i = r.begin(); i != r.end(); ++i)
          fails += !(cylinder_gap(g, x[i], y[i], z[i], 0.0) >= 0.0);
      }
    }
    acc.moved += flags.moved() ? 1 : 0;
    acc.failures += static_cast<std::int64_t>(fails);
    return acc;
  };
  const tbb::blocked_range<std::size_t> all(0, n, 4096);
  Partial total;
  auto join = [](Partial a, const Partial& b) {
    a.moved += b.moved;
    a.failures += b.failures;
    a.over_cap = a.over_cap || b.over_cap;
    a.walls.join(b.walls);
    return a;
  };
  if (n <= 8192) {
    total = body(all, Partial{});
  } else {
    total = tbb::parallel_reduce(all, Partial{}, body, join, tbb::static_partitioner{});
  }
  total.moved += travel.close_pass(exact, !total.over_cap, dt, [&] {
    return travel.measure(columns, n, step.half_skin2);
  });
  out.moved = total.moved;
  out.join(total.walls);
  if (total.failures > 0) {
    find_fault(p, n, g, vmax2, out); // rare path: name the first, deterministically
  }
}

// "particle <id> at (...): <why>" for a report with a fault (ids of the store: a partner may be
// a ghost copy).
std::string describe_fault(const ParticleStore& p, const StepReport& r, const StepModel& m);
// Why particle i could pass through a wall, for the words after "left the domain through a
// wall": its speed, and the impact speed and the load the wall's spring stops within
// dem.max_overlap (orb and islands count overlaps and stop only there).
std::string wall_passage(const ParticleStore& p, std::size_t i, const StepModel& m);

} // namespace cfddem::dem
