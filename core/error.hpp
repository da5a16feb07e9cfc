// Error types: configuration/input errors (exit code 2) and run-time failures (exit code 3).
// Each carries what a user needs to find the problem: the key or file, or the particle and time.
#pragma once

#include <stdexcept>
#include <string>

namespace cfddem {

// Bad scene key, bad input file, impossible value. `where` names the key or file (and line).
class ConfigError : public std::runtime_error {
public:
  ConfigError(std::string where, const std::string& what)
      : std::runtime_error(where.empty() ? what : where + ": " + what), where_(std::move(where)) {}
  const std::string& where() const { return where_; }

private:
  std::string where_;
};

// A run that went wrong (NaN, lost particle, overlap beyond a bound, unstable step).
class RunError : public std::runtime_error {
public:
  using std::runtime_error::runtime_error;
};

} // namespace cfddem
