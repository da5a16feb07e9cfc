// A scalar field on a MAC grid with ghost layers: cell-centred or face-centred data share one
// padded layout, so one index (and one set of strides) addresses every field of a grid.
#pragma once

#include <array>
#include <cstddef>
#include <span>
#include <vector>

#include "core/huge_page_allocator.hpp"

namespace cfddem::fluid {

// Ghost layers: limited MUSCL reconstruction reads two neighbours on each side of an edge, so
// two layers (one is enough for diffusion and projection alone).
inline constexpr int kGhostLayers = 2;

// Index space of n cells per axis: cells 0..n-1, faces 0..n (face i is the low face of cell i),
// padded by kGhostLayers on both sides; the extra slot at n + kGhostLayers holds the last face.
class GridLayout {
public:
  GridLayout() = default;
  explicit GridLayout(std::array<int, 3> cells) : cells_(cells) {
    std::size_t stride = 1;
    for (int a = 0; a < 3; ++a) {
      stride_[a] = static_cast<std::ptrdiff_t>(stride);
      stride *= static_cast<std::size_t>(cells[a] + 1 + 2 * kGhostLayers);
    }
    size_ = stride;
  }
  [[nodiscard]] std::size_t index(int i, int j, int k) const {
    return static_cast<std::size_t>((i + kGhostLayers) * stride_[0] +
                                    (j + kGhostLayers) * stride_[1] +
                                    (k + kGhostLayers) * stride_[2]);
  }
  [[nodiscard]] std::size_t index(const std::array<int, 3>& c) const {
    return index(c[0], c[1], c[2]);
  }
  [[nodiscard]] std::ptrdiff_t stride(int axis) const { return stride_[axis]; }
  [[nodiscard]] const std::array<int, 3>& cells() const { return cells_; }
  [[nodiscard]] std::size_t size() const { return size_; }

private:
  std::array<int, 3> cells_{};
  std::array<std::ptrdiff_t, 3> stride_{};
  std::size_t size_ = 0;
};

class GridField {
public:
  GridField() = default;
  explicit GridField(const GridLayout& layout, double value = 0.0)
      : layout_(layout), data_(layout.size(), value) {}

  [[nodiscard]] double& operator()(int i, int j, int k) { return data_[layout_.index(i, j, k)]; }
  [[nodiscard]] double operator()(int i, int j, int k) const {
    return data_[layout_.index(i, j, k)];
  }
  [[nodiscard]] double& operator[](std::size_t n) { return data_[n]; }
  [[nodiscard]] double operator[](std::size_t n) const { return data_[n]; }
  [[nodiscard]] const GridLayout& layout() const { return layout_; }
  [[nodiscard]] std::span<double> values() { return data_; }
  [[nodiscard]] std::span<const double> values() const { return data_; }
  void fill(double value) { data_.assign(data_.size(), value); }

private:
  GridLayout layout_;
  HugePageVector<double> data_; // large fields on huge pages (core/huge_page_allocator.hpp)
};

} // namespace cfddem::fluid
