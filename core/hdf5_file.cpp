#include "core/hdf5_file.hpp"

#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include "core/communicator_mpi.hpp"
#include "core/error.hpp"

namespace cfddem::h5 {

namespace {

void quiet_errors() {
  static const bool done = [] {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    return true;
  }();
  (void)done;
}

hsize_t product(const std::vector<hsize_t>& shape) {
  hsize_t n = 1;
  for (hsize_t s : shape) n *= s;
  return n;
}

// Write `bytes` to `path` (created or truncated) with write(2); on any failure remove what was
// written and throw RunError with the system's reason (ENOSPC: "No space left on device").
void write_bytes(const std::string& path, const std::vector<char>& bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0)
    throw RunError(fmt::format("cannot create '{}': {}", path, std::strerror(errno)));
  std::size_t done = 0;
  int err = 0;
  while (done < bytes.size()) {
    const ::ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0) {
      err = n < 0 ? errno : ENOSPC;
      break;
    }
    done += static_cast<std::size_t>(n);
  }
  if (::close(fd) != 0 && err == 0)
    err = errno;
  if (err != 0) {
    ::unlink(path.c_str());
    throw RunError(fmt::format("writing '{}' failed after {} of {} bytes: {}", path, done,
                               bytes.size(), std::strerror(err)));
  }
}

} // namespace

File File::create(const std::string& path) {
  quiet_errors();
  File f;
  f.path_ = path;
  // In memory, growing by 1 MiB, no backing store: close() writes the image.
  Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
  if (!fapl.valid() || H5Pset_fapl_core(fapl.get(), std::size_t{1} << 20, false) < 0)
    throw RunError(fmt::format("cannot set up HDF5 file '{}' in memory", path));
  f.file_ = Handle(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()), H5Fclose);
  if (!f.file_.valid()) throw RunError(fmt::format("cannot create HDF5 file '{}'", path));
  f.in_memory_ = true;
  return f;
}

File File::create_collective(const std::string& path, MPI_Comm comm) {
  quiet_errors();
  File f;
  f.path_ = path;
  Handle fapl(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
  if (!fapl.valid() || H5Pset_fapl_mpio(fapl.get(), comm, MPI_INFO_NULL) < 0)
    throw RunError(fmt::format("cannot set up MPI-IO for HDF5 file '{}'", path));
  f.file_ = Handle(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()), H5Fclose);
  if (!f.file_.valid()) throw RunError(fmt::format("cannot create HDF5 file '{}'", path));
  return f;
}

File File::create_collective(const std::string& path, const Communicator& comm) {
  return create_collective(path, mpi_comm(comm));
}

File File::open_read(const std::string& path) {
  quiet_errors();
  File f;
  f.path_ = path;
  if (H5Fis_hdf5(path.c_str()) <= 0)
    throw RunError(fmt::format("'{}' is not a readable HDF5 file (missing, truncated or corrupt)",
                               path));
  f.file_ = Handle(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!f.file_.valid())
    throw RunError(fmt::format("cannot open HDF5 file '{}' (truncated or corrupt?)", path));
  return f;
}

File File::open_write(const std::string& path) {
  quiet_errors();
  File f;
  f.path_ = path;
  f.file_ = Handle(H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT), H5Fclose);
  if (!f.file_.valid())
    throw RunError(fmt::format("cannot open HDF5 file '{}' to write", path));
  return f;
}

void File::close() {
  if (!file_.valid()) return;
  const hid_t id = file_.get();
  if (H5Fflush(id, H5F_SCOPE_GLOBAL) < 0)
    throw RunError(fmt::format("flushing HDF5 file '{}' failed (disk full?)", path_));
  if (!in_memory_) {
    file_.reset();
    return;
  }
  const ssize_t size = H5Fget_file_image(id, nullptr, 0);
  std::vector<char> image(size > 0 ? static_cast<std::size_t>(size) : 0);
  if (size <= 0 || H5Fget_file_image(id, image.data(), image.size()) != size)
    throw RunError(fmt::format("cannot take the image of HDF5 file '{}'", path_));
  file_.reset(); // the in-memory file: nothing to flush to a disk
  write_bytes(path_, image);
}

void File::create_group(const std::string& name) {
  Handle g(H5Gcreate2(file_.get(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
  if (!g.valid()) throw RunError(fmt::format("{}: cannot create group '{}'", path_, name));
}

bool File::exists(const std::string& name) const {
  // Check each path component (H5Lexists fails on a missing intermediate group).
  std::size_t pos = 0;
  while (true) {
    const std::size_t next = name.find('/', pos + 1);
    const std::string part = name.substr(0, next);
    if (!part.empty() && part != "/" && H5Lexists(file_.get(), part.c_str(), H5P_DEFAULT) <= 0)
      return false;
    if (next == std::string::npos) return true;
    pos = next;
  }
}

void File::write_raw(const std::string& name, hid_t type, const void* data, std::size_t n,
                     std::vector<hsize_t> shape) {
  if (product(shape) != n)
    throw RunError(fmt::format("{}: dataset '{}' has {} values for its shape", path_, name, n));
  Handle space(H5Screate_simple(static_cast<int>(shape.size()), shape.data(), nullptr), H5Sclose);
  Handle set(H5Dcreate2(file_.get(), name.c_str(), type, space.get(), H5P_DEFAULT, H5P_DEFAULT,
                        H5P_DEFAULT),
             H5Dclose);
  if (!space.valid() || !set.valid())
    throw RunError(fmt::format("{}: cannot create dataset '{}'", path_, name));
  if (n > 0 && H5Dwrite(set.get(), type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
    throw RunError(fmt::format("{}: writing dataset '{}' failed", path_, name));
}

void File::write(const std::string& name, std::span<const double> d, std::vector<hsize_t> s) {
  write_raw(name, H5T_NATIVE_DOUBLE, d.data(), d.size(), std::move(s));
}
void File::write(const std::string& name, std::span<const std::int64_t> d,
                 std::vector<hsize_t> s) {
  write_raw(name, H5T_NATIVE_INT64, d.data(), d.size(), std::move(s));
}
void File::write(const std::string& name, std::span<const std::uint32_t> d,
                 std::vector<hsize_t> s) {
  write_raw(name, H5T_NATIVE_UINT32, d.data(), d.size(), std::move(s));
}

void File::write_rows_raw(const std::string& name, hid_t type, const void* data, std::size_t n,
                          hsize_t rows_total, hsize_t row_offset, hsize_t width) {
  const hsize_t rows = width > 0 ? n / width : 0;
  if (width == 0 || rows * width != n || row_offset + rows > rows_total)
    throw RunError(fmt::format("{}: dataset '{}': {} values do not fit rows {}..{} of {}", path_,
                               name, n, row_offset, row_offset + rows, rows_total));
  const int rank = width == 1 ? 1 : 2;
  const hsize_t dims[2] = {rows_total, width};
  Handle space(H5Screate_simple(rank, dims, nullptr), H5Sclose);
  Handle set(H5Dcreate2(file_.get(), name.c_str(), type, space.get(), H5P_DEFAULT, H5P_DEFAULT,
                        H5P_DEFAULT),
             H5Dclose);
  if (!space.valid() || !set.valid())
    throw RunError(fmt::format("{}: cannot create dataset '{}'", path_, name));
  const hsize_t start[2] = {row_offset, 0}, count[2] = {rows, width};
  Handle mem(H5Screate_simple(rank, count, nullptr), H5Sclose);
  if (rows == 0) {
    H5Sselect_none(space.get());
    H5Sselect_none(mem.get());
  } else if (H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start, nullptr, count, nullptr) < 0) {
    throw RunError(fmt::format("{}: selecting rows of dataset '{}' failed", path_, name));
  }
  Handle xfer(H5Pcreate(H5P_DATASET_XFER), H5Pclose);
  H5Pset_dxpl_mpio(xfer.get(), H5FD_MPIO_COLLECTIVE);
  if (H5Dwrite(set.get(), type, mem.get(), space.get(), xfer.get(), data) < 0)
    throw RunError(fmt::format("{}: collective write of dataset '{}' failed", path_, name));
}

void File::write_block(const std::string& name, std::span<const double> local,
                       std::vector<hsize_t> shape, std::vector<hsize_t> start,
                       std::vector<hsize_t> count) {
  const std::size_t rank = shape.size();
  hsize_t n = 1;
  bool fits = rank > 0 && start.size() == rank && count.size() == rank;
  for (std::size_t a = 0; fits && a < rank; ++a) {
    n *= count[a];
    fits = start[a] + count[a] <= shape[a];
  }
  if (!fits || n != local.size())
    throw RunError(fmt::format("{}: dataset '{}': a block of {} values does not fit", path_, name,
                               local.size()));
  Handle space(H5Screate_simple(static_cast<int>(rank), shape.data(), nullptr), H5Sclose);
  Handle set(H5Dcreate2(file_.get(), name.c_str(), H5T_NATIVE_DOUBLE, space.get(), H5P_DEFAULT,
                        H5P_DEFAULT, H5P_DEFAULT),
             H5Dclose);
  if (!space.valid() || !set.valid())
    throw RunError(fmt::format("{}: cannot create dataset '{}'", path_, name));
  Handle mem(H5Screate_simple(static_cast<int>(rank), count.data(), nullptr), H5Sclose);
  if (n == 0) {
    H5Sselect_none(space.get());
    H5Sselect_none(mem.get());
  } else if (H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                                 nullptr) < 0) {
    throw RunError(fmt::format("{}: selecting a block of dataset '{}' failed", path_, name));
  }
  Handle xfer(H5Pcreate(H5P_DATASET_XFER), H5Pclose);
  H5Pset_dxpl_mpio(xfer.get(), H5FD_MPIO_COLLECTIVE);
  if (H5Dwrite(set.get(), H5T_NATIVE_DOUBLE, mem.get(), space.get(), xfer.get(), local.data()) < 0)
    throw RunError(fmt::format("{}: collective write of dataset '{}' failed", path_, name));
}

void File::write_rows(const std::string& name, std::span<const double> d, hsize_t total,
                      hsize_t offset, hsize_t width) {
  write_rows_raw(name, H5T_NATIVE_DOUBLE, d.data(), d.size(), total, offset, width);
}
void File::write_rows(const std::string& name, std::span<const std::int64_t> d, hsize_t total,
                      hsize_t offset, hsize_t width) {
  write_rows_raw(name, H5T_NATIVE_INT64, d.data(), d.size(), total, offset, width);
}

template <class T> Array<T> File::read_raw(const std::string& name, hid_t type) const {
  if (!exists(name)) throw RunError(fmt::format("{}: dataset '{}' is missing", path_, name));
  Handle set(H5Dopen2(file_.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  if (!set.valid()) throw RunError(fmt::format("{}: cannot open dataset '{}'", path_, name));
  Handle space(H5Dget_space(set.get()), H5Sclose);
  const int rank = space.valid() ? H5Sget_simple_extent_ndims(space.get()) : -1;
  if (rank < 0 || rank > 2)
    throw RunError(fmt::format("{}: dataset '{}' has an unexpected shape", path_, name));
  Array<T> a;
  a.shape.resize(static_cast<std::size_t>(rank));
  H5Sget_simple_extent_dims(space.get(), a.shape.data(), nullptr);
  a.values.resize(product(a.shape));
  if (!a.values.empty() &&
      H5Dread(set.get(), type, H5S_ALL, H5S_ALL, H5P_DEFAULT, a.values.data()) < 0)
    throw RunError(fmt::format("{}: reading dataset '{}' failed (truncated or corrupt file?)",
                               path_, name));
  return a;
}

std::vector<hsize_t> File::shape(const std::string& name) const {
  if (!exists(name))
    throw RunError(fmt::format("{}: dataset '{}' is missing", path_, name));
  Handle set(H5Dopen2(file_.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  Handle space(set.valid() ? H5Dget_space(set.get()) : H5I_INVALID_HID, H5Sclose);
  const int rank = space.valid() ? H5Sget_simple_extent_ndims(space.get()) : -1;
  if (rank < 0)
    throw RunError(fmt::format("{}: cannot open dataset '{}'", path_, name));
  std::vector<hsize_t> dims(static_cast<std::size_t>(rank));
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  return dims;
}

std::vector<double> File::read_block(const std::string& name, const std::vector<hsize_t>& start,
                                     const std::vector<hsize_t>& count) const {
  const std::vector<hsize_t> dims = shape(name);
  bool fits = start.size() == dims.size() && count.size() == dims.size();
  for (std::size_t a = 0; fits && a < dims.size(); ++a)
    fits = start[a] + count[a] <= dims[a];
  if (!fits)
    throw RunError(fmt::format("{}: the block asked of dataset '{}' lies outside it", path_, name));
  std::vector<double> v(product(count));
  if (v.empty())
    return v;
  Handle set(H5Dopen2(file_.get(), name.c_str(), H5P_DEFAULT), H5Dclose);
  Handle space(set.valid() ? H5Dget_space(set.get()) : H5I_INVALID_HID, H5Sclose);
  Handle mem(H5Screate_simple(static_cast<int>(count.size()), count.data(), nullptr), H5Sclose);
  if (!space.valid() || !mem.valid() ||
      H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                          nullptr) < 0 ||
      H5Dread(set.get(), H5T_NATIVE_DOUBLE, mem.get(), space.get(), H5P_DEFAULT, v.data()) < 0)
    throw RunError(fmt::format("{}: reading a block of dataset '{}' failed (truncated or corrupt "
                               "file?)",
                               path_, name));
  return v;
}

Array<double> File::read_double(const std::string& name) const {
  return read_raw<double>(name, H5T_NATIVE_DOUBLE);
}
Array<std::int64_t> File::read_int64(const std::string& name) const {
  return read_raw<std::int64_t>(name, H5T_NATIVE_INT64);
}
Array<std::uint32_t> File::read_uint32(const std::string& name) const {
  return read_raw<std::uint32_t>(name, H5T_NATIVE_UINT32);
}

void File::write_attr(const std::string& name, hid_t type, const void* v, const std::string& on) {
  Handle space(H5Screate(H5S_SCALAR), H5Sclose);
  Handle a(H5Acreate_by_name(file_.get(), on.c_str(), name.c_str(), type, space.get(),
                             H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT),
           H5Aclose);
  if (!a.valid() || H5Awrite(a.get(), type, v) < 0)
    throw RunError(fmt::format("{}: cannot write attribute '{}' on '{}'", path_, name, on));
}

void File::read_attr(const std::string& name, hid_t type, void* v, const std::string& on) const {
  if (H5Aexists_by_name(file_.get(), on.c_str(), name.c_str(), H5P_DEFAULT) <= 0)
    throw RunError(fmt::format("{}: attribute '{}' on '{}' is missing", path_, name, on));
  Handle a(H5Aopen_by_name(file_.get(), on.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT),
           H5Aclose);
  if (!a.valid() || H5Aread(a.get(), type, v) < 0)
    throw RunError(fmt::format("{}: cannot read attribute '{}' on '{}'", path_, name, on));
}

void File::attribute(const std::string& name, double v, const std::string& on) {
  write_attr(name, H5T_NATIVE_DOUBLE, &v, on);
}
void File::attribute(const std::string& name, std::int64_t v, const std::string& on) {
  write_attr(name, H5T_NATIVE_INT64, &v, on);
}
void File::attribute(const std::string& name, const std::string& v, const std::string& on) {
  Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(type.get(), v.empty() ? 1 : v.size());
  H5Tset_strpad(type.get(), H5T_STR_NULLPAD);
  write_attr(name, type.get(), v.empty() ? "" : v.data(), on);
}

double File::read_attribute_double(const std::string& name, const std::string& on) const {
  double v = 0.0;
  read_attr(name, H5T_NATIVE_DOUBLE, &v, on);
  return v;
}
std::int64_t File::read_attribute_int64(const std::string& name, const std::string& on) const {
  std::int64_t v = 0;
  read_attr(name, H5T_NATIVE_INT64, &v, on);
  return v;
}
std::string File::read_attribute_string(const std::string& name, const std::string& on) const {
  if (H5Aexists_by_name(file_.get(), on.c_str(), name.c_str(), H5P_DEFAULT) <= 0)
    throw RunError(fmt::format("{}: attribute '{}' on '{}' is missing", path_, name, on));
  Handle a(H5Aopen_by_name(file_.get(), on.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT),
           H5Aclose);
  Handle t(a.valid() ? H5Aget_type(a.get()) : H5I_INVALID_HID, H5Tclose);
  if (!t.valid() || H5Tget_class(t.get()) != H5T_STRING || H5Tis_variable_str(t.get()) > 0)
    throw RunError(fmt::format("{}: attribute '{}' is not a fixed-length string", path_, name));
  const std::size_t n = H5Tget_size(t.get());
  std::string s(n, '\0');
  Handle mem(H5Tcopy(H5T_C_S1), H5Tclose);
  H5Tset_size(mem.get(), n);
  H5Tset_strpad(mem.get(), H5T_STR_NULLPAD);
  if (H5Aread(a.get(), mem.get(), s.data()) < 0)
    throw RunError(fmt::format("{}: cannot read attribute '{}'", path_, name));
  while (!s.empty() && s.back() == '\0') s.pop_back();
  return s;
}

} // namespace cfddem::h5
