#include "core/simd_level.hpp"

#include <algorithm>
#include <cstdlib>
#include <string>

#include "core/error.hpp"

namespace cfddem {

SimdLevel cpu_simd_level() {
#if defined(CFDDEM_SIMD_COPIES)
  __builtin_cpu_init();
  if (__builtin_cpu_supports("x86-64-v4"))
    return SimdLevel::x86_64_v4;
  if (__builtin_cpu_supports("x86-64-v3"))
    return SimdLevel::x86_64_v3;
#endif
  return SimdLevel::x86_64;
}

std::string_view simd_level_name(SimdLevel level) {
  switch (level) {
  case SimdLevel::x86_64_v4:
    return "x86-64-v4";
  case SimdLevel::x86_64_v3:
    return "x86-64-v3";
  case SimdLevel::x86_64:
    break;
  }
  return "x86-64";
}

SimdLevel parse_simd_level(std::string_view text) {
  for (const SimdLevel l : {SimdLevel::x86_64, SimdLevel::x86_64_v3, SimdLevel::x86_64_v4})
    if (text == simd_level_name(l))
      return l;
  throw ConfigError("CFDDEM_SIMD", "'" + std::string(text) +
                                       "' is not an instruction set level: expected x86-64, "
                                       "x86-64-v3 or x86-64-v4");
}

SimdLevel simd_level() {
  // A function-local static: initialised once, thread-safely; a throw leaves it to the next call.
  static const SimdLevel level = [] {
    const SimdLevel cpu = cpu_simd_level();
    const char* cap = std::getenv("CFDDEM_SIMD");
    if (cap == nullptr || *cap == '\0')
      return cpu;
    return std::min(cpu, parse_simd_level(cap));
  }();
  return level;
}

} // namespace cfddem
