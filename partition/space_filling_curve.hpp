// Morton (Z-order) and Hilbert keys of points in a 3-D domain, and the permutation that sorts
// boxes along either curve: the order the knapsack cuts into contiguous, compact rank chunks.
#pragma once

#include "partition/aabb.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <vector>

namespace cfddem::partition {

enum class CurveKind { morton, hilbert };

// 21 bits per axis fill a 63-bit key.
inline constexpr int kCurveBits = 21;

// Cell of the 2^bits grid over `domain` holding p; the domain's hi faces are clamped into the
// last cell. Throws std::invalid_argument for a point outside the closed domain or NaN.
[[nodiscard]] std::array<std::uint32_t, 3>
curve_cell(const Aabb& domain, const std::array<double, 3>& p, int bits = kCurveBits);

// Bit b of axis a lands at key bit 3b + a: x is the fastest axis, so the 2x2x2 cells in key
// order are (0,0,0) (1,0,0) (0,1,0) (1,1,0) (0,0,1) ... `bits` <= 21.
[[nodiscard]] std::uint64_t morton_key(std::array<std::uint32_t, 3> cell, int bits = kCurveBits);

// Hilbert index (Skilling 2004, "Programming the Hilbert curve", AIP Conf. Proc. 707): cells
// consecutive in key are face neighbours; the curve starts at cell (0,0,0). `bits` <= 21.
[[nodiscard]] std::uint64_t hilbert_key(std::array<std::uint32_t, 3> cell, int bits = kCurveBits);

[[nodiscard]] std::uint64_t curve_key(CurveKind kind, std::array<std::uint32_t, 3> cell,
                                      int bits = kCurveBits);

// Permutation of `centres` sorted by curve key over `domain`, ties by index (stable).
[[nodiscard]] std::vector<std::uint32_t> sfc_order(std::span<const std::array<double, 3>> centres,
                                                   const Aabb& domain, CurveKind kind);
// Same over the centres' own bounding box.
[[nodiscard]] std::vector<std::uint32_t> sfc_order(std::span<const std::array<double, 3>> centres,
                                                   CurveKind kind);

} // namespace cfddem::partition
