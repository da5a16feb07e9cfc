// libFuzzer target: arbitrary bytes as a scene file. Every input must either load (SceneConfig
// parse + read_scene validation + describe_scene) or throw ConfigError with a message; anything
// else (a crash, a sanitizer report, another exception type, a hang) is a finding.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "core/error.hpp"
#include "core/scene.hpp"
#include "core/scene_config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    auto cfg = cfddem::SceneConfig::from_string(text, "fuzz input");
    // Exercise the command-line override path with the input's first line too.
    const std::size_t eol = text.find('\n');
    if (eol != std::string_view::npos && text.substr(0, eol).find('=') != std::string_view::npos)
      cfg.apply_override(std::string(text.substr(0, eol)));
    (void)cfg.flatten();
    const cfddem::Scene s = cfddem::read_scene(cfg, "fuzz");
    (void)cfddem::describe_scene(s);
  } catch (const cfddem::ConfigError& e) {
    if (std::string_view(e.what()).empty()) __builtin_trap(); // errors must say something
  }
  return 0;
}
