// Contact islands: the connected components of a graph given as a list of edges (pairs that
// could touch within a sub-iteration). Single-linkage clustering, the minimum-spanning-tree idea
// of the seed paper's conclusions, by union-find with path halving and union by index.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

namespace cfddem::partition {

struct Islands {
  // Component of each vertex, numbered 0, 1, ... in the order of their smallest vertex; a vertex
  // with no edge is a component of its own.
  std::vector<std::uint32_t> label;
  // Members of component c: members[first[c] .. first[c+1]), each component in increasing
  // vertex order.
  std::vector<std::uint32_t> first, members;
  std::uint32_t count() const { return static_cast<std::uint32_t>(first.size()) - 1; }
  std::uint32_t size(std::uint32_t c) const { return first[c + 1] - first[c]; }
};

// Components of the graph on n vertices with edges (a[q], b[q]). Deterministic: the result
// depends only on the edge set, not on the edges' order. Throws std::invalid_argument for an
// edge naming a vertex >= n or spans of different lengths.
[[nodiscard]] Islands connected_components(std::size_t n, std::span<const std::uint32_t> a,
                                           std::span<const std::uint32_t> b);

// The same, reusing `out`'s storage (no allocation once it has grown).
void connected_components(std::size_t n, std::span<const std::uint32_t> a,
                          std::span<const std::uint32_t> b, Islands& out,
                          std::vector<std::uint32_t>& parent_scratch);

} // namespace cfddem::partition
