// A thin RAII wrapper over the HDF5 C API (the C++ H5:: API has no MPI-IO calls, HighFive is not
// in Debian 12): files, groups, contiguous datasets of double / int64 / uint32 (written with any
// number of dimensions, read back with up to two), and scalar attributes. Every failure throws
// RunError naming the file and object; HDF5's own error stack printing is turned off.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <hdf5.h>
#include <mpi.h>

#include "core/communicator.hpp"

namespace cfddem::h5 {

// Owns one hid_t and closes it with the matching H5*close.
class Handle {
public:
  Handle() = default;
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = H5I_INVALID_HID; }
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      id_ = o.id_, close_ = o.close_;
      o.id_ = H5I_INVALID_HID;
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { reset(); }
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  void reset() {
    if (id_ >= 0 && close_) close_(id_);
    id_ = H5I_INVALID_HID;
  }

private:
  hid_t id_ = H5I_INVALID_HID;
  herr_t (*close_)(hid_t) = nullptr;
};

// A dataset read back: values in C order and the shape.
template <class T> struct Array {
  std::vector<T> values;
  std::vector<hsize_t> shape;
};

class File {
public:
  // Create (truncating) a file for writing. The file is built in memory (HDF5's core driver)
  // and written to `path` by close() with plain write(2) calls: a full disk then fails in our
  // own write, which reports it and removes the partial file, instead of in HDF5's flush, which
  // left a half-closed file that crashed the library's clean-up in MPI_Finalize. Nothing
  // reaches `path` before close().
  static File create(const std::string& path);
  // Create (truncating) a file that every rank of `comm` writes into with MPI-IO (parallel
  // HDF5): collective, every rank calls it and every later call on the file in the same order.
  static File create_collective(const std::string& path, MPI_Comm comm);
  static File create_collective(const std::string& path, const Communicator& comm);
  // Open an existing file read-only; throws RunError if it is not a readable HDF5 file.
  static File open_read(const std::string& path);
  // Open an existing file to add to it (one process: e.g. rank 0 after a collective write).
  static File open_write(const std::string& path);

  void create_group(const std::string& name);
  // Datasets of any shape ({n}, {n, m}, {nz, ny, nx, 3}, ...); data.size() = the product.
  void write(const std::string& name, std::span<const double> data, std::vector<hsize_t> shape);
  void write(const std::string& name, std::span<const std::int64_t> data,
             std::vector<hsize_t> shape);
  void write(const std::string& name, std::span<const std::uint32_t> data,
             std::vector<hsize_t> shape);
  // Collective (a file from create_collective): dataset {rows_total} (width 1) or {rows_total,
  // width}; this rank writes its `local.size() / width` rows from row `row_offset` on.
  void write_rows(const std::string& name, std::span<const double> local, hsize_t rows_total,
                  hsize_t row_offset, hsize_t width);
  void write_rows(const std::string& name, std::span<const std::int64_t> local,
                  hsize_t rows_total, hsize_t row_offset, hsize_t width);
  // Collective: dataset of shape `shape`; this rank writes the block of extents `count` from
  // `start` (data.size() = the product of count; a zero count writes nothing).
  void write_block(const std::string& name, std::span<const double> local,
                   std::vector<hsize_t> shape, std::vector<hsize_t> start,
                   std::vector<hsize_t> count);
  // Scalar attributes on the root group (or on object `on`).
  void attribute(const std::string& name, double v, const std::string& on = "/");
  void attribute(const std::string& name, std::int64_t v, const std::string& on = "/");
  void attribute(const std::string& name, const std::string& v, const std::string& on = "/");

  bool exists(const std::string& name) const;
  Array<double> read_double(const std::string& name) const;
  Array<std::int64_t> read_int64(const std::string& name) const;
  Array<std::uint32_t> read_uint32(const std::string& name) const;
  // The dataset's shape (any number of dimensions).
  std::vector<hsize_t> shape(const std::string& name) const;
  // The block of extents `count` from `start` of a double dataset of any shape, in C order
  // (a rank's box of a whole-grid dataset).
  std::vector<double> read_block(const std::string& name, const std::vector<hsize_t>& start,
                                 const std::vector<hsize_t>& count) const;
  double read_attribute_double(const std::string& name, const std::string& on = "/") const;
  std::int64_t read_attribute_int64(const std::string& name, const std::string& on = "/") const;
  std::string read_attribute_string(const std::string& name, const std::string& on = "/") const;

  // Flush and close (errors surface here rather than in a destructor); a file from create()
  // is written to its path here. Throws RunError naming the file and the system's reason.
  void close();
  const std::string& path() const { return path_; }

private:
  void write_raw(const std::string& name, hid_t type, const void* data, std::size_t n,
                 std::vector<hsize_t> shape);
  template <class T> Array<T> read_raw(const std::string& name, hid_t type) const;
  void write_rows_raw(const std::string& name, hid_t type, const void* data, std::size_t n,
                      hsize_t rows_total, hsize_t row_offset, hsize_t width);
  void write_attr(const std::string& name, hid_t type, const void* v, const std::string& on);
  void read_attr(const std::string& name, hid_t type, void* v, const std::string& on) const;
  Handle file_;
  std::string path_;
  bool in_memory_ = false; // create(): the image is written to path_ by close()
};

} // namespace cfddem::h5
