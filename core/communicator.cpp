#include "core/communicator.hpp"

#include <algorithm>
#include <limits>
#include <vector>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"

namespace cfddem {

namespace {
template <class T> MPI_Datatype mpi_type();
template <> MPI_Datatype mpi_type<double>() {
  return MPI_DOUBLE;
}
template <> MPI_Datatype mpi_type<std::int64_t>() {
  return MPI_INT64_T;
}

template <class T> void reduce(const Communicator& c, std::span<T> v, MPI_Op op) {
  if (c.size() == 1 || v.empty())
    return;
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(T)), true);
  MpiWait w(c);
  MPI_Allreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), mpi_type<T>(), op, mpi_comm(c));
}
} // namespace

Communicator Communicator::world() {
  Communicator c;
  c.handle_ = static_cast<int>(MPI_Comm_c2f(MPI_COMM_WORLD));
  MPI_Comm_rank(MPI_COMM_WORLD, &c.rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &c.size_);
  return c;
}

void Communicator::sum(std::span<double> v) const {
  reduce(*this, v, MPI_SUM);
}
void Communicator::sum(std::span<std::int64_t> v) const {
  reduce(*this, v, MPI_SUM);
}
void Communicator::max(std::span<double> v) const {
  reduce(*this, v, MPI_MAX);
}
void Communicator::max(std::span<std::int64_t> v) const {
  reduce(*this, v, MPI_MAX);
}
void Communicator::min(std::span<std::int64_t> v) const {
  reduce(*this, v, MPI_MIN);
}

namespace {
// The user operation of sum_max: buffer[0] = number of summed entries (the same on every rank),
// then the sums, then the maxima.
void sum_then_max(void* in, void* inout, int* len, MPI_Datatype*) {
  const auto* a = static_cast<const double*>(in);
  auto* b = static_cast<double*>(inout);
  const auto n = static_cast<int>(a[0]);
  for (int k = 1; k <= n; ++k)
    b[k] += a[k];
  for (int k = n + 1; k < *len; ++k)
    b[k] = a[k] > b[k] ? a[k] : b[k];
}
} // namespace

void Communicator::sum_max(std::span<double> sums, std::span<double> maxes) const {
  if (size_ == 1)
    return;
  static MPI_Op op = [] {
    MPI_Op o;
    MPI_Op_create(&sum_then_max, 1, &o);
    return o;
  }();
  std::vector<double> buf(1 + sums.size() + maxes.size());
  buf[0] = static_cast<double>(sums.size());
  std::copy(sums.begin(), sums.end(), buf.begin() + 1);
  std::copy(maxes.begin(), maxes.end(), buf.begin() + 1 + static_cast<std::ptrdiff_t>(sums.size()));
  count_messages::collective(static_cast<std::int64_t>(buf.size() * sizeof(double)), true);
  {
    MpiWait w(*this);
    MPI_Allreduce(MPI_IN_PLACE, buf.data(), static_cast<int>(buf.size()), MPI_DOUBLE, op,
                  mpi_comm(*this));
  }
  std::copy_n(buf.begin() + 1, sums.size(), sums.begin());
  std::copy_n(buf.begin() + 1 + static_cast<std::ptrdiff_t>(sums.size()), maxes.size(),
              maxes.begin());
}

void Communicator::max_begin(std::span<std::int64_t> v) const {
  if (size_ == 1 || v.empty())
    return;
  if (!request_)
    request_ = std::make_shared<MPI_Request>(MPI_REQUEST_NULL); // once: no allocation per step
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(std::int64_t)), true);
  MPI_Iallreduce(MPI_IN_PLACE, v.data(), static_cast<int>(v.size()), MPI_INT64_T, MPI_MAX,
                 mpi_comm(*this), static_cast<MPI_Request*>(request_.get()));
}

void Communicator::max_wait() const {
  if (!request_)
    return;
  MpiWait w(*this);
  MPI_Wait(static_cast<MPI_Request*>(request_.get()), MPI_STATUS_IGNORE); // null: returns at once
}

std::int64_t Communicator::sum(std::int64_t v) const {
  sum(std::span<std::int64_t>(&v, 1));
  return v;
}

double Communicator::max(double v) const {
  max(std::span<double>(&v, 1));
  return v;
}

std::vector<double> Communicator::gather(double v) const {
  if (size_ == 1)
    return {v};
  std::vector<double> all(rank_ == 0 ? static_cast<std::size_t>(size_) : 0);
  count_messages::collective(sizeof(double), false);
  MpiWait w(*this);
  MPI_Gather(&v, 1, MPI_DOUBLE, all.data(), 1, MPI_DOUBLE, 0, mpi_comm(*this));
  return all;
}

namespace {
template <class T> std::vector<T> gather_all(const Communicator& c, std::span<const T> v) {
  if (c.size() == 1)
    return {v.begin(), v.end()};
  const bool root = c.rank() == 0;
  int n = static_cast<int>(v.size());
  std::vector<int> counts(root ? static_cast<std::size_t>(c.size()) : 0), offsets(counts.size());
  count_messages::collective(sizeof(int), false);
  count_messages::collective(static_cast<std::int64_t>(v.size() * sizeof(T)), false);
  MpiWait w(c);
  MPI_Gather(&n, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, mpi_comm(c));
  int total = 0;
  for (std::size_t r = 0; r < counts.size(); ++r)
    offsets[r] = total, total += counts[r];
  std::vector<T> all(static_cast<std::size_t>(total));
  MPI_Gatherv(v.data(), n, mpi_type<T>(), all.data(), counts.data(), offsets.data(), mpi_type<T>(),
              0, mpi_comm(c));
  return all;
}
} // namespace

std::vector<double> Communicator::gather(std::span<const double> v) const {
  return gather_all(*this, v);
}

std::vector<std::int64_t> Communicator::gather(std::span<const std::int64_t> v) const {
  return gather_all(*this, v);
}

std::string Communicator::agree_on_error(std::int64_t key, const std::string& message) const {
  constexpr std::int64_t kNoError = std::numeric_limits<std::int64_t>::max();
  if (size_ == 1)
    return message;
  // The smallest key, then the lowest rank holding it, which broadcasts its message.
  std::int64_t k = message.empty() ? kNoError : key;
  min(std::span<std::int64_t>(&k, 1));
  if (k == kNoError)
    return {};
  std::int64_t root = !message.empty() && key == k ? rank_ : size_;
  min(std::span<std::int64_t>(&root, 1));
  std::string text = rank_ == root ? message : std::string();
  MpiWait w(*this);
  auto len = static_cast<long long>(text.size());
  count_messages::collective(sizeof(len), false);
  MPI_Bcast(&len, 1, MPI_LONG_LONG, static_cast<int>(root), mpi_comm(*this));
  text.resize(static_cast<std::size_t>(len));
  count_messages::collective(len, false);
  MPI_Bcast(text.data(), static_cast<int>(len), MPI_CHAR, static_cast<int>(root), mpi_comm(*this));
  return text;
}

} // namespace cfddem
