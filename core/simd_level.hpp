// The instruction set the vectorised particle kernels run with (dem/kick_drift_range.cpp): the
// portable build targets baseline x86-64 (SSE2, two doubles per instruction), and the kernels
// whose time is instructions rather than memory also carry copies compiled for x86-64-v3 (AVX2)
// and x86-64-v4 (AVX-512), picked once at run time from what the CPU supports. Every copy does
// the same operations in the same order per particle (no contraction: -ffp-contract=off, no
// reassociation), so the results are bitwise the same at every level; only the speed differs.
#pragma once

#include <string_view>

namespace cfddem {

// The x86-64 micro-architecture levels (the psABI's names).
enum class SimdLevel : int { x86_64 = 0, x86_64_v3 = 1, x86_64_v4 = 2 };

// The highest level this CPU supports; x86_64 on a compiler or a CPU without the copies.
SimdLevel cpu_simd_level();

// The level the kernels run at: the CPU's, capped by the environment variable CFDDEM_SIMD
// ("x86-64", "x86-64-v3" or "x86-64-v4") for side-by-side measurements or to rule the copies
// out. Read once; a value that is not one of the three is a ConfigError naming the variable.
SimdLevel simd_level();

// "x86-64", "x86-64-v3", "x86-64-v4".
std::string_view simd_level_name(SimdLevel level);

// Marks a lambda passed to at_simd_level: its body is inlined into the copy compiled for the
// level, and so are the functions it calls that are themselves always inlined (the kernels'
// loops). A call it does not inline runs that function's own (baseline) code.
#define CFDDEM_SIMD_BODY __attribute__((always_inline))

namespace detail {
#if defined(CFDDEM_SIMD_COPIES)
template <class F> [[gnu::target("arch=x86-64-v3")]] void at_v3(F& f) {
  f();
}
template <class F> [[gnu::target("arch=x86-64-v4")]] void at_v4(F& f) {
  f();
}
#endif
} // namespace detail

// Runs f() compiled for `level` (f: a lambda marked CFDDEM_SIMD_BODY whose loops are always
// inlined): the loops are vectorised for that instruction set, and a level without a copy runs
// the baseline one. Every copy computes what the baseline does, in the same order (the flags
// above), so only the speed depends on the level.
template <class F> inline void at_simd_level([[maybe_unused]] SimdLevel level, F&& f) {
#if defined(CFDDEM_SIMD_COPIES)
  if (level == SimdLevel::x86_64_v4)
    return detail::at_v4(f);
  if (level == SimdLevel::x86_64_v3)
    return detail::at_v3(f);
#endif
  f();
}

// Kernels whose loops vectorize only from restrict parameters (GCC keeps the restrict of a called
// function's parameters, not of an inlined one's or of local pointers) come as types with static
// noinline member functions, one type per level. MAKE(NAME, ...) defines such a type, putting
// __VA_ARGS__ after gnu::noinline in each member's attribute list;
// CFDDEM_SIMD_COPY_TYPES(MAKE, Prefix) defines PrefixX86_64, PrefixV3 and PrefixV4, the last two
// compiled for x86-64-v3 and -v4 where the build carries copies (else as the build targets).
#if defined(CFDDEM_SIMD_COPIES)
#define CFDDEM_SIMD_COPY_TYPES(MAKE, PREFIX)                                                       \
  MAKE(PREFIX##X86_64)                                                                             \
  MAKE(PREFIX##V3, , gnu::target("arch=x86-64-v3"))                                                \
  MAKE(PREFIX##V4, , gnu::target("arch=x86-64-v4"))
#else
#define CFDDEM_SIMD_COPY_TYPES(MAKE, PREFIX)                                                       \
  MAKE(PREFIX##X86_64)                                                                             \
  MAKE(PREFIX##V3)                                                                                 \
  MAKE(PREFIX##V4)
#endif

// Calls f with a value of the copy type for `level` (CFDDEM_SIMD_COPY_TYPES's three), the
// baseline one where the build has no copies.
template <class X86_64, class V3, class V4, class F>
inline void with_copy_at([[maybe_unused]] SimdLevel level, F&& f) {
#if defined(CFDDEM_SIMD_COPIES)
  if (level == SimdLevel::x86_64_v4)
    return f(V4{});
  if (level == SimdLevel::x86_64_v3)
    return f(V3{});
#endif
  f(X86_64{});
}

// The level named `text` (the three names above); a ConfigError naming CFDDEM_SIMD otherwise.
SimdLevel parse_simd_level(std::string_view text);

} // namespace cfddem
