// libFuzzer target: arbitrary bytes as a particle CSV file (x,y,z,vx,vy,vz,diameter,density).
// Every input must either load or throw ConfigError with a message; anything else is a finding.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>

#include <unistd.h>

#include "core/error.hpp"
#include "core/initial_conditions.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::string path = "/tmp/cfddem_fuzz_" + std::to_string(::getpid()) + ".csv";
  if (std::FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data, 1, size, f);
    std::fclose(f);
  } else {
    return 0;
  }
  try {
    const cfddem::ParticleStore p = cfddem::read_particle_csv(path);
    (void)p.size();
  } catch (const cfddem::ConfigError& e) {
    if (std::string_view(e.what()).empty()) __builtin_trap();
  }
  return 0;
}
