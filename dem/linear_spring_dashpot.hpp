// Linear spring-dashpot normal contact between two spheres (Cundall & Strack 1979;
// docs/theory.md §2), and its tangential spring with Coulomb friction and history (MFIX classic /
// LIGGGHTS convention). Kernels on scalars: no allocation, no threads, no I/O.
#pragma once

#include <cmath>

namespace cfddem::dem {

struct NormalLaw {
  double k;        // k_n [N/m]
  double eta_coef; // eta_n = eta_coef * sqrt(m_eff)   (contact_damping.hpp)
};

// Magnitude of the normal force along n (n from i to j; positive = repulsive):
// F_n = k delta + eta v_n, v_n = (v_i - v_j).n the approach speed. No tensile clamp: the peers
// and MFIX-Exa do not clamp, and clamping changes the restitution (docs/theory.md §2).
inline double normal_force(const NormalLaw& law, double m_eff, double delta, double v_n) {
  return law.k * delta + law.eta_coef * std::sqrt(m_eff) * v_n;
}

struct TangentialLaw {
  double k_t;      // tangential spring [N/m]
  double eta_coef; // eta_t = eta_coef * sqrt(m_eff)
  double mu;       // Coulomb coefficient
};

// Tangential force with history xi (the accumulated tangential displacement), updated in place.
// vt: tangential slip velocity at the contact; n: unit normal; fn_abs: |F_n|.
// xi is first rotated into the current tangent plane (LIGGGHTS), then xi += dt vt,
// F_t = -k_t xi - eta_t vt; if |F_t| > mu |F_n| the contact slides: F_t is scaled onto the
// Coulomb cone and xi is reset to the spring length that gives it (docs/theory.md §2).
inline void tangential_force(const TangentialLaw& law, double m_eff, double dt, double fn_abs,
                             const double n[3], const double vt[3], double xi[3], double ft[3]) {
  const double xn = xi[0] * n[0] + xi[1] * n[1] + xi[2] * n[2];
  xi[0] -= xn * n[0], xi[1] -= xn * n[1], xi[2] -= xn * n[2];
  xi[0] += dt * vt[0], xi[1] += dt * vt[1], xi[2] += dt * vt[2];
  const double eta = law.eta_coef * std::sqrt(m_eff);
  for (int a = 0; a < 3; ++a) ft[a] = -law.k_t * xi[a] - eta * vt[a];
  const double f2 = ft[0] * ft[0] + ft[1] * ft[1] + ft[2] * ft[2];
  const double fmax = law.mu * fn_abs;
  if (f2 > fmax * fmax) {
    const double s = fmax / std::sqrt(f2);
    for (int a = 0; a < 3; ++a) {
      ft[a] *= s;
      xi[a] = -ft[a] / law.k_t;
    }
  }
}

} // namespace cfddem::dem
