// Run-time switches to template arguments. The kernels take their switches (an external force,
// friction, recording...) as template parameters so that each combination compiles to its own
// branch-free loop; a caller holds them as bools. with_flags(f, a, b, ...) calls f once with one
// std::bool_constant per bool, in order, so the choice among the 2^n instantiations is written
// once instead of as a tree of ternaries:
//   with_flags([&](auto ext, auto fr) { island_sums<ext, fr>(n); }, ext_.active(), friction);
// Call it outside a hot loop (one choice for the whole loop), not per element.
#pragma once

#include <type_traits>

namespace cfddem::dem {

template <class F> decltype(auto) with_flags(F&& f) {
  return f();
}

template <class F, class... Rest> decltype(auto) with_flags(F&& f, bool first, Rest... rest) {
  // Fix the first flag, then choose the rest with it bound in front.
  auto fixed = [&](auto flag) -> decltype(auto) {
    return with_flags([&](auto... more) -> decltype(auto) { return f(flag, more...); }, rest...);
  };
  if (first)
    return fixed(std::true_type{});
  return fixed(std::false_type{});
}

} // namespace cfddem::dem
