// The fine stepping of an orb leaf batch (dem/orb_scheme.hpp), on any rank count: the contact
// pass over the batch's rows, the wall contacts, the synchronised velocity of a recorded step and
// the variable-step leapfrog kick-drift. The kernels take small views of the particle columns
// (structs of pointers into the store's SoA) and know nothing of leaves, ranks or threads.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <span>

#include "dem/contact_kernels.hpp"
#include "dem/friction_kernels.hpp"
#include "dem/kick_drift_range.hpp"

namespace cfddem::dem {

// The views below are spans over the store's slots (and the rows' arrays), each with its length,
// as dem/particle_views.hpp: a column that is absent is empty.
//
// The columns a batch advances, indexed by the store's slots: positions, velocities and the
// contact force (written), the half step h_prev of each particle (written), and what is read.
// fex/fey/fez: the external force, read only by the External instantiations.
struct LeafLive {
  std::span<double> x, y, z, vx, vy, vz, fx, fy, fz, hp;
  std::span<const double> rad, mass, im;
  std::span<const double> fex, fey, fez;
};

// Read-only positions and velocities at the start of the sub-iteration: what a particle reads of
// its partners in other leaves (or on other ranks).
struct LeafFrozen {
  std::span<const double> x, y, z, vx, vy, vz;
};

// Rows: the particles act[a0, a1) with partners; particle i's own-leaf partners
// nb[off[i], mid[i]) (read live), other partners nb[mid[i], off[i + 1]) (read frozen).
struct LeafRows {
  std::span<const std::uint32_t> act, off, mid, nb;
};

// With friction: the spins (read live) and torques (written) of the store's slots, 1 / I, the
// spins at the start of the sub-iteration (what a partner in another leaf is read at), and the
// tangential history per row entry (nb's indexing: entry s is particle i's record of nb[s]).
struct LeafSpin {
  std::span<double> wx, wy, wz, tx, ty, tz;
  std::span<const double> ii;
  std::span<const double> gwx, gwy, gwz;
  std::span<double> hx, hy, hz;
};

// The largest overlap ratio seen and the overlaps beyond the bound (dem.max_overlap radii).
struct OverlapTally {
  double max_ratio = 0.0;
  std::int64_t violations = 0;
  void join(const OverlapTally& o) {
    max_ratio = std::max(max_ratio, o.max_ratio);
    violations += o.violations;
  }
};

namespace detail {
// The loop of leaf_contact_pass. Its pointers are restrict parameters: GCC takes no-alias from
// parameters only, not from restrict locals, and with locals it reloaded the columns after
// every force store (+2% instructions on the dense orb benchmark).
[[gnu::always_inline]] inline void leaf_contact_loop(
    std::uint32_t a0, std::uint32_t a1, const std::uint32_t* __restrict act,
    const std::uint32_t* __restrict off, const std::uint32_t* __restrict mid,
    const std::uint32_t* __restrict nb, const double* __restrict x, const double* __restrict y,
    const double* __restrict z, const double* __restrict vx, const double* __restrict vy,
    const double* __restrict vz, const double* __restrict gx, const double* __restrict gy,
    const double* __restrict gz, const double* __restrict gvx, const double* __restrict gvy,
    const double* __restrict gvz, const double* __restrict rad, const double* __restrict mass,
    double* __restrict fx, double* __restrict fy, double* __restrict fz, const DomainGeometry& g,
    const StepModel& m, OverlapTally& tally) {
  const double lim = m.max_overlap;
  double max_ratio = tally.max_ratio;
  std::int64_t violations = tally.violations;
  for (std::uint32_t q = a0; q < a1; ++q) {
    const std::uint32_t i = act[q];
    const double xi = x[i], yi = y[i], zi = z[i];
    const double vxi = vx[i], vyi = vy[i], vzi = vz[i], ri = rad[i], mi = mass[i];
    double ax = 0.0, ay = 0.0, az = 0.0;
    auto partner = [&](std::uint32_t j, double xj, double yj, double zj, double vxj, double vyj,
                       double vzj) {
      const double delta =
          add_normal_contact(m, g.image(xj - xi, 0), g.image(yj - yi, 1), g.image(zj - zi, 2), ri,
                             rad[j], mi, mass[j], vxi - vxj, vyi - vyj, vzi - vzj, ax, ay, az);
      if (delta <= 0.0)
        return;
      const double ratio = delta / std::min(ri, rad[j]);
      max_ratio = std::max(max_ratio, ratio);
      violations += ratio > lim;
    };
    for (std::uint32_t s = off[i]; s < mid[i]; ++s) {
      const std::uint32_t j = nb[s];
      partner(j, x[j], y[j], z[j], vx[j], vy[j], vz[j]);
    }
    for (std::uint32_t s = mid[i]; s < off[i + 1]; ++s) {
      const std::uint32_t j = nb[s];
      partner(j, gx[j], gy[j], gz[j], gvx[j], gvy[j], gvz[j]);
    }
    fx[i] = ax, fy[i] = ay, fz[i] = az;
  }
  tally.max_ratio = max_ratio;
  tally.violations = violations;
}
} // namespace detail

// Contact pass over the rows act[a0, a1): each particle's force is the sum of its pair forces,
// own-leaf partners live, the others frozen; the sum runs in row order (rows are sorted by id).
// Inlined into the batch loop: called as a function (once the loop had a third template
// parameter, the column) it cost orb 0.9% more instructions on HCS 1222 (callgrind).
[[gnu::always_inline]] inline void leaf_contact_pass(std::uint32_t a0, std::uint32_t a1, const LeafRows& r,
                              const LeafLive& p, const LeafFrozen& f, const DomainGeometry& g,
                              const StepModel& m, OverlapTally& tally) {
  detail::leaf_contact_loop(a0, a1, r.act.data(), r.off.data(), r.mid.data(), r.nb.data(),
                            p.x.data(), p.y.data(), p.z.data(), p.vx.data(), p.vy.data(),
                            p.vz.data(), f.x.data(), f.y.data(), f.z.data(), f.vx.data(),
                            f.vy.data(), f.vz.data(), p.rad.data(), p.mass.data(), p.fx.data(),
                            p.fy.data(), p.fz.data(), g, m, tally);
}

// The frictional contact pass over the rows act[a0, a1): leaf_contact_pass's sums with the
// tangential spring of each entry advanced over the local step hk (its increment hk v_t, with
// v_t the slip at the half step the step starts from: the explicit scheme's update for a
// constant step, and over a sub-iteration the increments add up to dt_sp), and the torques.
inline void leaf_frictional_contact_pass(std::uint32_t a0, std::uint32_t a1, const LeafRows& r,
                                         const LeafLive& p, const LeafFrozen& f, const LeafSpin& w,
                                         double hk, const DomainGeometry& g, const StepModel& m,
                                         OverlapTally& tally) {
  const double lim = m.max_overlap;
  for (std::uint32_t q = a0; q < a1; ++q) {
    const std::uint32_t i = r.act[q];
    const double xi = p.x[i], yi = p.y[i], zi = p.z[i];
    const double vxi = p.vx[i], vyi = p.vy[i], vzi = p.vz[i], ri = p.rad[i], mi = p.mass[i];
    const double wi[3] = {w.wx[i], w.wy[i], w.wz[i]};
    double a[3] = {0.0, 0.0, 0.0}, tq[3] = {0.0, 0.0, 0.0};
    auto partner = [&](std::uint32_t s, std::uint32_t j, double xj, double yj, double zj,
                       double vxj, double vyj, double vzj, const double wj[3]) {
      double h[3] = {w.hx[s], w.hy[s], w.hz[s]};
      const double delta = add_frictional_contact(
          m, g.image(xj - xi, 0), g.image(yj - yi, 1), g.image(zj - zi, 2), ri, p.rad[j], mi,
          p.mass[j], vxi - vxj, vyi - vyj, vzi - vzj, wi, wj, hk, h, a, tq);
      w.hx[s] = h[0], w.hy[s] = h[1], w.hz[s] = h[2];
      if (delta <= 0.0)
        return;
      const double ratio = delta / std::min(ri, p.rad[j]);
      tally.max_ratio = std::max(tally.max_ratio, ratio);
      tally.violations += ratio > lim;
    };
    for (std::uint32_t s = r.off[i]; s < r.mid[i]; ++s) {
      const std::uint32_t j = r.nb[s];
      const double wj[3] = {w.wx[j], w.wy[j], w.wz[j]};
      partner(s, j, p.x[j], p.y[j], p.z[j], p.vx[j], p.vy[j], p.vz[j], wj);
    }
    for (std::uint32_t s = r.mid[i]; s < r.off[i + 1]; ++s) {
      const std::uint32_t j = r.nb[s];
      const double wj[3] = {w.gwx[j], w.gwy[j], w.gwz[j]};
      partner(s, j, f.x[j], f.y[j], f.z[j], f.vx[j], f.vy[j], f.vz[j], wj);
    }
    p.fx[i] = a[0], p.fy[i] = a[1], p.fz[i] = a[2];
    w.tx[i] = tq[0], w.ty[i] = tq[1], w.tz[i] = tq[2];
  }
}

// Wall contacts of the particles [b, e): each adds its walls' normal forces to the force its row
// summed (a particle without a row has no pair force, so the wall force replaces what f held).
inline void add_wall_forces(std::uint32_t b, std::uint32_t e, const std::uint32_t* off,
                            const LeafLive& p, const DomainGeometry& g, const NormalLaw& wall,
                            double limit, OverlapTally& tally) {
  for (std::uint32_t i = b; i < e; ++i) {
    const bool row = off[i + 1] > off[i];
    double f[3] = {row ? p.fx[i] : 0.0, row ? p.fy[i] : 0.0, row ? p.fz[i] : 0.0};
    const double pos[3] = {p.x[i], p.y[i], p.z[i]}, vel[3] = {p.vx[i], p.vy[i], p.vz[i]};
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (int side = 0; side < 2; ++side) {
        const double sg = side ? 1.0 : -1.0;
        const double delta = side ? p.rad[i] - (g.hi[a] - pos[a]) : p.rad[i] - (pos[a] - g.lo[a]);
        if (delta <= 0.0)
          continue;
        f[a] -= sg * normal_force(wall, p.mass[i], delta, sg * vel[a]);
        tally.max_ratio = std::max(tally.max_ratio, delta / p.rad[i]);
        tally.violations += delta > limit * p.rad[i];
      }
    }
    p.fx[i] = f[0], p.fy[i] = f[1], p.fz[i] = f[2];
  }
}

// add_wall_forces with friction: each wall's tangential force and torque too (the explicit
// scheme's wall pass); a particle without a row starts from zero force and torque.
inline void add_frictional_wall_forces(std::uint32_t b, std::uint32_t e, const std::uint32_t* off,
                                       const LeafLive& p, const LeafSpin& w,
                                       const DomainGeometry& g, const StepModel& m,
                                       OverlapTally& tally) {
  for (std::uint32_t i = b; i < e; ++i) {
    const bool row = off[i + 1] > off[i];
    double f[3] = {row ? p.fx[i] : 0.0, row ? p.fy[i] : 0.0, row ? p.fz[i] : 0.0};
    double tq[3] = {row ? w.tx[i] : 0.0, row ? w.ty[i] : 0.0, row ? w.tz[i] : 0.0};
    const double pos[3] = {p.x[i], p.y[i], p.z[i]}, vel[3] = {p.vx[i], p.vy[i], p.vz[i]};
    const double ri = p.rad[i], mi = p.mass[i];
    for (int a = 0; a < 3; ++a) {
      if (g.periodic[a])
        continue;
      for (int side = 0; side < 2; ++side) {
        const double sg = side ? 1.0 : -1.0;
        const double delta = side ? ri - (g.hi[a] - pos[a]) : ri - (pos[a] - g.lo[a]);
        if (delta <= 0.0)
          continue;
        const double fn = normal_force(m.wall, mi, delta, sg * vel[a]);
        f[a] -= sg * fn;
        tally.max_ratio = std::max(tally.max_ratio, delta / ri);
        tally.violations += delta > m.max_overlap * ri;
        const double wv[3] = {w.wx[i], w.wy[i], w.wz[i]};
        add_wall_friction(m.wall_t, mi, ri, fn, a, sg, vel, wv, f, tq);
      }
    }
    p.fx[i] = f[0], p.fy[i] = f[1], p.fz[i] = f[2];
    w.tx[i] = tq[0], w.ty[i] = tq[1], w.tz[i] = tq[2];
  }
}

// The wall contacts of particle i (add_wall_contacts: the planar walls of the non-periodic axes,
// and with Cylinder the curved wall of a column) added to f (and tq, with friction).
template <bool Friction, bool Cylinder>
inline void add_particle_walls(std::uint32_t i, const LeafLive& p,
                               [[maybe_unused]] const LeafSpin& w, const DomainGeometry& g,
                               const StepModel& m, double f[3], double tq[3],
                               OverlapTally& tally) {
  const double ri = p.rad[i], mi = p.mass[i];
  const double pos[3] = {p.x[i], p.y[i], p.z[i]}, vel[3] = {p.vx[i], p.vy[i], p.vz[i]};
  add_wall_contacts<Friction, Cylinder>(
      g, m.wall, m.wall_t, pos, vel, ri, [&] { return mi; },
      [&](double s[3]) {
        if constexpr (Friction)
          s[0] = w.wx[i], s[1] = w.wy[i], s[2] = w.wz[i];
      },
      f, tq,
      [&](double delta) {
        tally.max_ratio = std::max(tally.max_ratio, delta / ri);
        tally.violations += delta > m.max_overlap * ri;
      });
}

// The walls of a cylindrical column (domain.shape = "cylinder") on the particles [b, e), in
// place of add_wall_forces or add_frictional_wall_forces: the curved wall and the planar walls
// along its axis, through the explicit scheme's helper (add_wall_contacts), added to the force
// (and torque) the row summed; a particle without a row starts from zero.
template <bool Friction>
inline void add_column_wall_forces(std::uint32_t b, std::uint32_t e, const std::uint32_t* off,
                                   const LeafLive& p, [[maybe_unused]] const LeafSpin& w,
                                   const DomainGeometry& g, const StepModel& m,
                                   OverlapTally& tally) {
  for (std::uint32_t i = b; i < e; ++i) {
    const bool row = off[i + 1] > off[i];
    double f[3] = {row ? p.fx[i] : 0.0, row ? p.fy[i] : 0.0, row ? p.fz[i] : 0.0};
    double tq[3] = {0.0, 0.0, 0.0};
    if constexpr (Friction)
      tq[0] = row ? w.tx[i] : 0.0, tq[1] = row ? w.ty[i] : 0.0, tq[2] = row ? w.tz[i] : 0.0;
    add_particle_walls<Friction, true>(i, p, w, g, m, f, tq, tally);
    p.fx[i] = f[0], p.fy[i] = f[1], p.fz[i] = f[2];
    if constexpr (Friction)
      w.tx[i] = tq[0], w.ty[i] = tq[1], w.tz[i] = tq[2];
  }
}

// The walls of the particles `idx` (planar, and a column's with Cylinder), added to the force
// each holds (the global steps: the pair pass's scatter wrote it). No friction.
template <bool Cylinder>
inline void add_listed_wall_forces(std::span<const std::uint32_t> idx, const LeafLive& p,
                                   const DomainGeometry& g, const StepModel& m,
                                   OverlapTally& tally) {
  for (const std::uint32_t i : idx) {
    double f[3] = {p.fx[i], p.fy[i], p.fz[i]}, tq[3] = {0.0, 0.0, 0.0};
    add_particle_walls<false, Cylinder>(i, p, LeafSpin{}, g, m, f, tq, tally);
    p.fx[i] = f[0], p.fy[i] = f[1], p.fz[i] = f[2];
  }
}

// The spin kick of local step k of a batch [b, e), before leaf_kick_drift (which overwrites
// h_prev): w += T / I s over the span s of the translational kick (h_prev + h/2 at k = 0, then
// (h_before + h)/2), the explicit scheme's w += T (1/I) dt for a constant step.
inline void leaf_spin_kick(std::uint32_t b, std::uint32_t e, const LeafLive& p, const LeafSpin& w,
                           std::int64_t k, double h_before, double hk) {
  const double half = 0.5 * hk, sk = 0.5 * h_before + half;
  for (std::uint32_t i = b; i < e; ++i) {
    const double s = w.ii[i] * (k == 0 ? p.hp[i] + half : sk);
    w.wx[i] += w.tx[i] * s, w.wy[i] += w.ty[i] * s, w.wz[i] += w.tz[i] * s;
  }
}

// The synchronised velocities v(n) = v(n-1/2) + a(n) h_prev of the particles [b, e) (a recorded
// step of the variable-step leapfrog), into sv.
template <bool External>
inline void synchronised_velocities(std::uint32_t b, std::uint32_t e, const LeafLive& p,
                                    const std::array<double, 3>& gravity, double* svx, double* svy,
                                    double* svz) {
  for (std::uint32_t i = b; i < e; ++i) {
    if constexpr (External) {
      svx[i] = p.vx[i] + ((p.fx[i] + p.fex[i]) * p.im[i] + gravity[0]) * p.hp[i];
      svy[i] = p.vy[i] + ((p.fy[i] + p.fey[i]) * p.im[i] + gravity[1]) * p.hp[i];
      svz[i] = p.vz[i] + ((p.fz[i] + p.fez[i]) * p.im[i] + gravity[2]) * p.hp[i];
    } else {
      svx[i] = p.vx[i] + (p.fx[i] * p.im[i] + gravity[0]) * p.hp[i];
      svy[i] = p.vy[i] + (p.fy[i] * p.im[i] + gravity[1]) * p.hp[i];
      svz[i] = p.vz[i] + (p.fz[i] * p.im[i] + gravity[2]) * p.hp[i];
    }
  }
}

// One local step of a batch [b, e): its length, the previous one's (k > 0), the step's index k
// of K, and the skin test against the reference positions `ref` (squared half skin).
struct LeafStep {
  std::int64_t k = 0, K = 1;
  double h_before = 0.0, hk = 0.0, half_skin2 = 0.0;
};

// Local step k of K of a batch [b, e): dem/kick_drift_range.hpp's leaf_kick_drift (the one
// variable-step leapfrog) over the batch's columns, the reference positions `ref` for the skin
// test.
template <bool External, bool Moved = true>
inline void leaf_kick_drift(std::uint32_t b, std::uint32_t e, const LeafLive& p,
                            const LeafFrozen& ref, const LeafStep& st,
                            const std::array<double, 3>& gravity, std::uint64_t& still,
                            double cap2 = 0.0) {
  const std::size_t n = e - b;
  const auto part = [b, n](auto column) { return column.subspan(b, n); };
  KickDriftColumns c{part(p.x),  part(p.y),   part(p.z),   part(p.vx),  part(p.vy), part(p.vz),
                     part(p.fx), part(p.fy),  part(p.fz),  {},          {},         {},
                     part(p.im), part(ref.x), part(ref.y), part(ref.z), part(p.hp)};
  if constexpr (External)
    c.ex = part(p.fex), c.ey = part(p.fey), c.ez = part(p.fez);
  leaf_kick_drift<External, Moved>(st.k, st.K, c, st.h_before, st.hk, gravity, st.half_skin2, still,
                                   cap2);
}

} // namespace cfddem::dem
