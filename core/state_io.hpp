// What a scheme writes into a checkpoint and reads back, without knowing the file: named arrays
// (doubles, int64s, uint32s) and scalar attributes, under paths the scheme chooses. apps/
// implements both over the HDF5 checkpoint, which checksums the arrays in the order put.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace cfddem {

class StateWriter {
public:
  virtual ~StateWriter() = default;
  virtual void group(const std::string& name) = 0;
  virtual void put(const std::string& name, const std::vector<double>& v) = 0;
  virtual void put(const std::string& name, const std::vector<std::int64_t>& v) = 0;
  virtual void put(const std::string& name, const std::vector<std::uint32_t>& v) = 0;
  virtual void attribute(const std::string& name, double v) = 0;
  virtual void attribute(const std::string& name, std::int64_t v) = 0;
};

// Each read checks the array is one-dimensional with n values (kAny: any length) and throws
// RunError otherwise; the caller turns it into the checkpoint's ConfigError.
class StateReader {
public:
  static constexpr std::size_t kAny = static_cast<std::size_t>(-1);
  virtual ~StateReader() = default;
  virtual bool exists(const std::string& name) const = 0;
  virtual std::vector<double> doubles(const std::string& name, std::size_t n) = 0;
  virtual std::vector<std::int64_t> int64s(const std::string& name, std::size_t n) = 0;
  virtual std::vector<std::uint32_t> uint32s(const std::string& name, std::size_t n) = 0;
  virtual double attribute_double(const std::string& name) const = 0;
  virtual std::int64_t attribute_int64(const std::string& name) const = 0;
};

// Three arrays of one vector quantity, named prefix + "x" + suffix and so on (x_ref, history_x).
// The y and z arrays are read with the x array's length.
inline void put_xyz(StateWriter& w, const std::string& prefix, const std::string& suffix,
                    const std::vector<double>& x, const std::vector<double>& y,
                    const std::vector<double>& z) {
  w.put(prefix + "x" + suffix, x);
  w.put(prefix + "y" + suffix, y);
  w.put(prefix + "z" + suffix, z);
}
inline void read_xyz(StateReader& r, const std::string& prefix, const std::string& suffix,
                     std::size_t n, std::vector<double>& x, std::vector<double>& y,
                     std::vector<double>& z) {
  x = r.doubles(prefix + "x" + suffix, n);
  y = r.doubles(prefix + "y" + suffix, x.size());
  z = r.doubles(prefix + "z" + suffix, x.size());
}

} // namespace cfddem
