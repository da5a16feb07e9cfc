// Space-filling curve keys: bit interleaving (Morton) and Skilling's transpose (Hilbert).
#include "partition/space_filling_curve.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace cfddem::partition {
namespace {

void check_cell(const std::array<std::uint32_t, 3>& cell, int bits) {
  if (bits < 1 || bits > kCurveBits) {
    throw std::invalid_argument("space-filling curve: bits must be in [1, 21], got " +
                                std::to_string(bits));
  }
  for (const std::uint32_t c : cell) {
    if ((c >> bits) != 0) {
      throw std::invalid_argument("space-filling curve: cell index needs more than " +
                                  std::to_string(bits) + " bits");
    }
  }
}

// Spreads the low 21 bits of v to every third bit (the usual magic-number dilation).
std::uint64_t dilate3(std::uint64_t v) {
  v &= 0x1fffffULL;
  v = (v | (v << 32)) & 0x1f00000000ffffULL;
  v = (v | (v << 16)) & 0x1f0000ff0000ffULL;
  v = (v | (v << 8)) & 0x100f00f00f00f00fULL;
  v = (v | (v << 4)) & 0x10c30c30c30c30c3ULL;
  v = (v | (v << 2)) & 0x1249249249249249ULL;
  return v;
}

} // namespace

std::array<std::uint32_t, 3> curve_cell(const Aabb& domain, const std::array<double, 3>& p,
                                        int bits) {
  check_cell({0, 0, 0}, bits);
  const auto n = static_cast<double>(std::uint64_t{1} << bits);
  const std::uint32_t last = (std::uint32_t{1} << bits) - 1;
  std::array<std::uint32_t, 3> cell{};
  for (int a = 0; a < 3; ++a) {
    if (!(domain.lo[a] <= p[a] && p[a] <= domain.hi[a])) {
      throw std::invalid_argument("space-filling curve: point outside the domain");
    }
    const double t = (p[a] - domain.lo[a]) / domain.extent(a) * n;
    // t may reach n on the hi face (or by rounding just below it): that is the last cell.
    cell[a] = std::min(static_cast<std::uint32_t>(t), last);
  }
  return cell;
}

std::uint64_t morton_key(std::array<std::uint32_t, 3> cell, int bits) {
  check_cell(cell, bits);
  return dilate3(cell[0]) | (dilate3(cell[1]) << 1) | (dilate3(cell[2]) << 2);
}

std::uint64_t hilbert_key(std::array<std::uint32_t, 3> cell, int bits) {
  check_cell(cell, bits);
  std::array<std::uint32_t, 3> x = cell;
  const std::uint32_t top = std::uint32_t{1} << (bits - 1);
  // Skilling's AxestoTranspose: undo the excess work of the inverse, then Gray-encode.
  for (std::uint32_t q = top; q > 1; q >>= 1) {
    const std::uint32_t p = q - 1;
    for (int i = 0; i < 3; ++i) {
      if ((x[i] & q) != 0) {
        x[0] ^= p;
      } else {
        const std::uint32_t t = (x[0] ^ x[i]) & p;
        x[0] ^= t;
        x[i] ^= t;
      }
    }
  }
  x[1] ^= x[0];
  x[2] ^= x[1];
  std::uint32_t t = 0;
  for (std::uint32_t q = top; q > 1; q >>= 1) {
    if ((x[2] & q) != 0) {
      t ^= q - 1;
    }
  }
  for (auto& xi : x) {
    xi ^= t;
  }
  // The transpose holds the index bits column-wise, x[0] most significant in each triple.
  return (dilate3(x[0]) << 2) | (dilate3(x[1]) << 1) | dilate3(x[2]);
}

std::uint64_t curve_key(CurveKind kind, std::array<std::uint32_t, 3> cell, int bits) {
  return kind == CurveKind::morton ? morton_key(cell, bits) : hilbert_key(cell, bits);
}

std::vector<std::uint32_t> sfc_order(std::span<const std::array<double, 3>> centres,
                                     const Aabb& domain, CurveKind kind) {
  if (centres.size() >= std::numeric_limits<std::uint32_t>::max()) {
    throw std::invalid_argument("sfc_order: more than 2^32-2 centres");
  }
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(centres.size());
  for (std::size_t i = 0; i < centres.size(); ++i) {
    keyed[i] = {curve_key(kind, curve_cell(domain, centres[i])), static_cast<std::uint32_t>(i)};
  }
  // Pairs compare by key, then index: a total order, so std::sort is as good as stable.
  std::sort(keyed.begin(), keyed.end());
  std::vector<std::uint32_t> order(centres.size());
  for (std::size_t k = 0; k < keyed.size(); ++k) {
    order[k] = keyed[k].second;
  }
  return order;
}

std::vector<std::uint32_t> sfc_order(std::span<const std::array<double, 3>> centres,
                                     CurveKind kind) {
  if (centres.empty()) {
    return {};
  }
  Aabb box{centres[0], centres[0]};
  for (const auto& c : centres) {
    for (int a = 0; a < 3; ++a) {
      box.lo[a] = std::min(box.lo[a], c[a]);
      box.hi[a] = std::max(box.hi[a], c[a]);
    }
  }
  // A flat axis (all centres in one plane) would divide by zero; any positive extent keys it 0.
  for (int a = 0; a < 3; ++a) {
    if (!(box.hi[a] > box.lo[a])) {
      box.hi[a] = box.lo[a] + std::max(1.0, std::abs(box.lo[a]));
    }
  }
  return sfc_order(centres, box, kind);
}

} // namespace cfddem::partition
