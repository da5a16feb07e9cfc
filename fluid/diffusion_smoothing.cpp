#include "fluid/diffusion_smoothing.hpp"

#include <cmath>
#include <stdexcept>
#include <vector>

namespace cfddem::fluid {

namespace {

// y = (I - D lap) x on the interior cells, flattened x-fastest.
void apply(const MacGrid& grid, const std::array<double, 3>& c, const std::vector<double>& x,
           std::vector<double>& y) {
  const auto& n = grid.cells();
  const auto at = [&](int i, int j, int k) {
    const auto nx = static_cast<std::size_t>(n[0]);
    const auto ny = static_cast<std::size_t>(n[1]);
    return static_cast<std::size_t>(i) +
           nx * (static_cast<std::size_t>(j) + ny * static_cast<std::size_t>(k));
  };
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const std::array<int, 3> cell = {i, j, k};
        const double xc = x[at(i, j, k)];
        double lap_sum = 0.0;
        for (int a = 0; a < 3; ++a) {
          for (const int side : {-1, 1}) {
            std::array<int, 3> nb = cell;
            nb[a] += side;
            if (nb[a] < 0 || nb[a] >= n[a]) {
              if (!grid.periodic(a)) {
                continue; // no flux through a non-periodic face
              }
              nb[a] = (nb[a] + n[a]) % n[a];
            }
            lap_sum += c[a] * (x[at(nb[0], nb[1], nb[2])] - xc);
          }
        }
        y[at(i, j, k)] = xc - lap_sum;
      }
    }
  }
}

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    s += a[i] * b[i];
  }
  return s;
}

} // namespace

SmoothingReport smooth_implicit(const MacGrid& grid, double diffusion, GridField& q,
                                double tolerance, int max_iterations) {
  if (diffusion < 0.0) {
    throw std::invalid_argument("deposition diffusion D must be >= 0");
  }
  SmoothingReport report;
  if (diffusion == 0.0) {
    return report;
  }
  const auto& n = grid.cells();
  const std::size_t count = static_cast<std::size_t>(n[0]) * n[1] * n[2];
  std::array<double, 3> c{};
  for (int a = 0; a < 3; ++a) {
    c[a] = diffusion / (grid.spacing(a) * grid.spacing(a));
  }
  std::vector<double> b(count), x(count), r(count), p(count), ap(count);
  std::size_t m = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        b[m++] = q(i, j, k);
      }
    }
  }
  x = b; // the smoothed field is close to the input: a good first guess
  apply(grid, c, x, ap);
  for (std::size_t i = 0; i < count; ++i) {
    r[i] = b[i] - ap[i];
  }
  p = r;
  const double b_norm = std::sqrt(dot(b, b));
  double rr = dot(r, r);
  int it = 0;
  while (it < max_iterations && std::sqrt(rr) > tolerance * b_norm) {
    apply(grid, c, p, ap);
    const double alpha = rr / dot(p, ap);
    for (std::size_t i = 0; i < count; ++i) {
      x[i] += alpha * p[i];
      r[i] -= alpha * ap[i];
    }
    const double rr_new = dot(r, r);
    for (std::size_t i = 0; i < count; ++i) {
      p[i] = r[i] + rr_new / rr * p[i];
    }
    rr = rr_new;
    ++it;
  }
  m = 0;
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        q(i, j, k) = x[m++];
      }
    }
  }
  report.iterations = it;
  report.relative_residual = b_norm > 0.0 ? std::sqrt(rr) / b_norm : 0.0;
  return report;
}

} // namespace cfddem::fluid
