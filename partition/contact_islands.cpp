#include "partition/contact_islands.hpp"

#include <stdexcept>

namespace cfddem::partition {

namespace {

// Root of v with path halving (every other node on the path points to its grandparent).
std::uint32_t find_root(std::vector<std::uint32_t>& parent, std::uint32_t v) {
  while (parent[v] != v) {
    parent[v] = parent[parent[v]];
    v = parent[v];
  }
  return v;
}

} // namespace

void connected_components(std::size_t n, std::span<const std::uint32_t> a,
                          std::span<const std::uint32_t> b, Islands& out,
                          std::vector<std::uint32_t>& parent) {
  if (a.size() != b.size())
    throw std::invalid_argument("connected_components: edge lists of different lengths");
  parent.resize(n);
  for (std::size_t v = 0; v < n; ++v) parent[v] = static_cast<std::uint32_t>(v);
  for (std::size_t q = 0; q < a.size(); ++q) {
    if (a[q] >= n || b[q] >= n)
      throw std::invalid_argument("connected_components: edge names a vertex out of range");
    const std::uint32_t ra = find_root(parent, a[q]), rb = find_root(parent, b[q]);
    // The smaller root wins, so every root is its component's smallest vertex whatever the
    // order of the edges.
    if (ra < rb) parent[rb] = ra;
    else if (rb < ra) parent[ra] = rb;
  }
  // Labels in order of the smallest vertex: a root is met before the rest of its component.
  out.label.resize(n);
  std::uint32_t count = 0;
  for (std::size_t v = 0; v < n; ++v) {
    const std::uint32_t r = find_root(parent, static_cast<std::uint32_t>(v));
    out.label[v] = r == v ? count++ : out.label[r];
  }
  out.first.assign(static_cast<std::size_t>(count) + 1, 0);
  for (std::size_t v = 0; v < n; ++v) ++out.first[out.label[v] + 1];
  for (std::uint32_t c = 0; c < count; ++c) out.first[c + 1] += out.first[c];
  out.members.resize(n);
  std::vector<std::uint32_t>& fill = parent; // no longer needed as a forest
  fill.assign(out.first.begin(), out.first.end() - 1);
  for (std::size_t v = 0; v < n; ++v) out.members[fill[out.label[v]]++] = static_cast<std::uint32_t>(v);
}

Islands connected_components(std::size_t n, std::span<const std::uint32_t> a,
                             std::span<const std::uint32_t> b) {
  Islands out;
  std::vector<std::uint32_t> parent;
  connected_components(n, a, b, out, parent);
  return out;
}

} // namespace cfddem::partition
