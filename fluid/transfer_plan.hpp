// The kernels of a set of particles at fixed positions, made once (Deposition::plan) and used by
// every transfer of one fluid step: the solid fraction, eps_g and u_g at the particles, the drag
// to the cells and the new gas at the particles are four passes over the same kernels. Where a
// kernel is separable (trilinear, dpvm cube; no round column) its cell weights are products of
// per-axis factors, w = (w_x w_y) w_z, so the plan keeps only each axis's factors and folded cell
// indices, and a pass multiplies them in the order the kernel functions do (bitwise their weights).
// Data: structure of arrays, a fixed number of slots per particle and axis.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace cfddem::fluid {

// Particle positions and radii as spans (structure of arrays).
struct ParticlePositions {
  std::span<const double> x, y, z, radius;
};

struct TransferPlan {
  ParticlePositions positions; // what the plan was made from (spans: the caller's arrays)
  std::size_t count = 0;
  // false: the kernels are not products of axis factors (dpvm sphere, a round column's solid
  // cells), or wider than 16 cells on an axis: every pass computes them from `positions`, and
  // the arrays below are empty.
  bool separable = false;
  // Slots per particle along each axis (the most cells a kernel covers); a particle's factors
  // and indices start at q * stride, x's slots first, then y's, then z's.
  std::array<int, 3> slots{};
  int stride = 0;
  // 2: every particle's kernel has two cells along every axis (the trilinear kernel), so the
  // passes walk it with fixed loop counts; 0: the counts are per particle (`cells`).
  int fixed_cells = 0;
  std::vector<std::uint8_t> cells; // 3 per particle: its kernel's cells along x, y, z
  std::vector<double> factor;      // per slot: the axis factor of the cell
  std::vector<std::int32_t> index; // per slot: the cell's folded index along its axis
};

} // namespace cfddem::fluid
