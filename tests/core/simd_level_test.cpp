// The instruction set level of the kernels' copies (core/simd_level.hpp): its names, what a
// bad CFDDEM_SIMD value says, and that the level in force never exceeds the CPU's.
#include <gtest/gtest.h>

#include <string>

#include "core/error.hpp"
#include "core/simd_level.hpp"

namespace cfddem {
namespace {

TEST(SimdLevel, NamesReadBackAndABadNameIsRefusedNamingTheVariable) {
  for (const SimdLevel l : {SimdLevel::x86_64, SimdLevel::x86_64_v3, SimdLevel::x86_64_v4})
    EXPECT_EQ(parse_simd_level(simd_level_name(l)), l);
  try {
    (void)parse_simd_level("avx2");
    FAIL() << "'avx2' was taken as a level";
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.where(), "CFDDEM_SIMD");
    EXPECT_NE(std::string(e.what()).find("'avx2'"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("x86-64-v3"), std::string::npos) << e.what();
  }
  EXPECT_THROW((void)parse_simd_level(""), ConfigError);
}

TEST(SimdLevel, TheLevelInForceIsOneTheCpuRuns) {
  EXPECT_LE(static_cast<int>(simd_level()), static_cast<int>(cpu_simd_level()));
}

} // namespace
} // namespace cfddem
