#include "core/particle_exchange.hpp"

#include <algorithm>
#include <bit>
#include <stdexcept>

#include "core/communicator_mpi.hpp"
#include "core/message_counts.hpp"
#include "core/sparse_exchange.hpp"

namespace cfddem {

namespace {

// The double fields that travel with a particle, in packing order (id travels as its bits).
std::vector<std::vector<double>*> carried(ParticleStore& p) {
  std::vector<std::vector<double>*> f{&p.x,  &p.y,      &p.z,    &p.vx,      &p.vy,
                                      &p.vz, &p.radius, &p.mass, &p.inv_mass};
  if (p.rotation)
    for (auto* v : {&p.wx, &p.wy, &p.wz, &p.inv_inertia})
      f.push_back(v);
  return f;
}

int stride_of(ParticleStore& p) {
  return static_cast<int>(carried(p).size()) + 1;
}

void pack(const std::vector<std::vector<double>*>& f, const ParticleStore& p, std::size_t i,
          const std::array<double, 3>& shift, std::vector<double>& buf) {
  for (std::size_t k = 0; k < f.size(); ++k)
    buf.push_back((*f[k])[i] + (k < 3 ? shift[k] : 0.0));
  buf.push_back(std::bit_cast<double>(p.id[i]));
}

// Append `count` particles packed in `buf` to the store.
void unpack_append(ParticleStore& p, std::span<const double> buf, std::size_t count) {
  const std::size_t first = p.size();
  p.resize(first + count);
  const auto f = carried(p);
  const std::size_t stride = f.size() + 1;
  for (std::size_t q = 0; q < count; ++q) {
    const double* in = buf.data() + q * stride;
    for (std::size_t k = 0; k < f.size(); ++k)
      (*f[k])[first + q] = in[k];
    p.id[first + q] = std::bit_cast<std::int64_t>(in[f.size()]);
  }
}

} // namespace

void ParticleExchange::exchange(std::span<const std::int64_t> send_counts,
                                std::span<const double> send,
                                std::vector<std::int64_t>& recv_counts, std::vector<double>& recv,
                                int stride, bool counts_known) {
  sparse_exchange(comm_, send_counts, send, recv_counts, recv, stride, counts_known);
}

std::size_t ParticleExchange::migrate(ParticleStore& p, std::span<const int> dest,
                                      std::span<std::vector<double>* const> payload) {
  const int ranks = comm_.size();
  if (dest.size() != p.size())
    throw std::invalid_argument("ParticleExchange::migrate: one destination per particle");
  for (const std::vector<double>* v : payload)
    if (v->size() != p.size())
      throw std::invalid_argument("ParticleExchange::migrate: one payload value per particle");
  std::vector<std::int64_t> counts(static_cast<std::size_t>(ranks), 0);
  for (const int r : dest) {
    if (r < 0 || r >= ranks)
      throw std::invalid_argument("ParticleExchange::migrate: destination rank out of range");
    ++counts[static_cast<std::size_t>(r)];
  }
  const int me = comm_.rank();
  counts[static_cast<std::size_t>(me)] = 0; // stayers are not copied
  // Pack leavers by destination rank (a counting sort keeps each rank's in index order).
  std::vector<std::size_t> at(static_cast<std::size_t>(ranks) + 1, 0);
  for (int r = 0; r < ranks; ++r)
    at[r + 1] = at[r] + static_cast<std::size_t>(counts[r]);
  std::vector<std::uint32_t> by_rank(at[ranks]), keep;
  keep.reserve(p.size() - at[ranks]);
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (dest[i] == me) {
      keep.push_back(static_cast<std::uint32_t>(i));
    } else {
      by_rank[at[dest[i]]++] = static_cast<std::uint32_t>(i);
    }
  }
  const std::size_t extra = payload.size();
  const int stride = stride_of(p) + static_cast<int>(extra);
  send_buf_.clear();
  send_buf_.reserve(by_rank.size() * static_cast<std::size_t>(stride));
  const auto fields = carried(p);
  for (const std::uint32_t i : by_rank) {
    pack(fields, p, i, {0.0, 0.0, 0.0}, send_buf_);
    for (const std::vector<double>* v : payload)
      send_buf_.push_back((*v)[i]);
  }
  std::vector<std::int64_t> recv_counts;
  exchange(counts, send_buf_, recv_counts, recv_buf_, stride, false);
  p.permute(keep); // a selection: the store shrinks to the stayers, in order
  std::size_t received = 0;
  for (const std::int64_t c : recv_counts)
    received += static_cast<std::size_t>(c);
  if (extra == 0) {
    unpack_append(p, recv_buf_, received);
  } else {
    // Split each record into the store's part and the payload's.
    const std::size_t base = static_cast<std::size_t>(stride_of(p));
    std::vector<double> store_part;
    store_part.reserve(received * base);
    for (std::vector<double>* v : payload) {
      std::vector<double> kept(keep.size());
      for (std::size_t k = 0; k < keep.size(); ++k)
        kept[k] = (*v)[keep[k]];
      v->swap(kept);
      v->reserve(keep.size() + received);
    }
    for (std::size_t q = 0; q < received; ++q) {
      const double* in = recv_buf_.data() + q * static_cast<std::size_t>(stride);
      store_part.insert(store_part.end(), in, in + base);
      for (std::size_t e = 0; e < extra; ++e)
        payload[e]->push_back(in[base + e]);
    }
    unpack_append(p, store_part, received);
  }
  // The store changed: any ghost plan refers to old indices.
  plan_.clear();
  send_counts_.assign(static_cast<std::size_t>(ranks), 0);
  recv_counts_.assign(static_cast<std::size_t>(ranks), 0);
  owned_ = p.size();
  recv_total_ = 0;
  return received;
}

std::size_t ParticleExchange::redistribute(ParticleStore& p, std::span<const int> dest,
                                           std::vector<Copy> ghosts,
                                           std::span<std::vector<double>* const> extra) {
  const int ranks = comm_.size(), me = comm_.rank();
  const std::size_t n = p.size();
  if (dest.size() != n)
    throw std::invalid_argument("ParticleExchange::redistribute: one destination per particle");
  for (const std::vector<double>* e : extra)
    if (e->size() != n)
      throw std::invalid_argument("ParticleExchange::redistribute: an extra column of the wrong "
                                  "size");
  for (const Copy& c : ghosts)
    if (c.rank < 0 || c.rank >= ranks || c.index >= n)
      throw std::invalid_argument("ParticleExchange::redistribute: bad ghost rank or index");
  // Per destination rank: its owned arrivals, then its ghosts (a flag travels with each).
  std::vector<std::vector<std::uint32_t>> own_to(static_cast<std::size_t>(ranks));
  std::vector<std::uint32_t> keep;
  keep.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    if (dest[i] < 0 || dest[i] >= ranks)
      throw std::invalid_argument("ParticleExchange::redistribute: destination rank out of range");
    if (dest[i] == me) {
      keep.push_back(static_cast<std::uint32_t>(i));
    } else {
      own_to[static_cast<std::size_t>(dest[i])].push_back(static_cast<std::uint32_t>(i));
    }
  }
  std::stable_sort(ghosts.begin(), ghosts.end(),
                   [](const Copy& a, const Copy& b) { return a.rank < b.rank; });
  const auto fields = carried(p);
  const int stride = stride_of(p) + static_cast<int>(extra.size()) + 1;
  std::vector<std::int64_t> counts(static_cast<std::size_t>(ranks), 0);
  send_buf_.clear();
  auto put = [&](std::uint32_t i, const std::array<double, 3>& shift, double ghost) {
    pack(fields, p, i, shift, send_buf_);
    for (const std::vector<double>* e : extra)
      send_buf_.push_back((*e)[i]);
    send_buf_.push_back(ghost);
  };
  std::size_t g = 0;
  for (int r = 0; r < ranks; ++r) {
    for (const std::uint32_t i : own_to[static_cast<std::size_t>(r)])
      put(i, {0.0, 0.0, 0.0}, 0.0);
    counts[static_cast<std::size_t>(r)] += static_cast<std::int64_t>(own_to[static_cast<std::size_t>(r)].size());
    for (; g < ghosts.size() && ghosts[g].rank == r; ++g, ++counts[static_cast<std::size_t>(r)])
      put(ghosts[g].index, ghosts[g].shift, 1.0);
  }
  std::vector<std::int64_t> recv_counts;
  exchange(counts, send_buf_, recv_counts, recv_buf_, stride, false);
  // Stayers, owned arrivals, ghosts; the extra columns alike.
  std::size_t arrivals = 0, received = 0;
  for (const std::int64_t c : recv_counts)
    received += static_cast<std::size_t>(c);
  for (std::size_t q = 0; q < received; ++q)
    arrivals += recv_buf_[q * static_cast<std::size_t>(stride) + static_cast<std::size_t>(stride) - 1] == 0.0;
  if (keep.size() != n) p.permute(keep); // nobody left: the store keeps its order
  const std::size_t owned = keep.size() + arrivals;
  for (std::vector<double>* e : extra) {
    std::vector<double> col(owned + received - arrivals);
    for (std::size_t k = 0; k < keep.size(); ++k)
      col[k] = (*e)[keep[k]];
    e->swap(col);
  }
  p.resize(owned + received - arrivals);
  const std::size_t base = static_cast<std::size_t>(stride_of(p));
  std::size_t next_owned = keep.size(), next_ghost = owned;
  for (std::size_t q = 0; q < received; ++q) {
    const double* in = recv_buf_.data() + q * static_cast<std::size_t>(stride);
    const std::size_t at = in[stride - 1] == 0.0 ? next_owned++ : next_ghost++;
    for (std::size_t k = 0; k < fields.size(); ++k)
      (*fields[k])[at] = in[k];
    p.id[at] = std::bit_cast<std::int64_t>(in[fields.size()]);
    for (std::size_t k = 0; k < extra.size(); ++k)
      (*extra[k])[at] = in[base + k];
  }
  plan_.clear();
  send_counts_.assign(static_cast<std::size_t>(ranks), 0);
  recv_counts_.assign(static_cast<std::size_t>(ranks), 0);
  owned_ = owned;
  recv_total_ = received - arrivals;
  return owned;
}

std::size_t ParticleExchange::build_ghosts(ParticleStore& p, std::size_t owned,
                                           std::vector<Copy> copies) {
  const int ranks = comm_.size();
  std::stable_sort(copies.begin(), copies.end(),
                   [](const Copy& a, const Copy& b) { return a.rank < b.rank; });
  plan_ = std::move(copies);
  owned_ = owned;
  p.resize(owned);
  send_counts_.assign(static_cast<std::size_t>(ranks), 0);
  send_buf_.clear();
  const auto fields = carried(p);
  for (const Copy& c : plan_) {
    if (c.rank < 0 || c.rank >= ranks || c.index >= owned)
      throw std::invalid_argument("ParticleExchange::build_ghosts: bad rank or index");
    ++send_counts_[static_cast<std::size_t>(c.rank)];
    pack(fields, p, c.index, c.shift, send_buf_);
  }
  exchange(send_counts_, send_buf_, recv_counts_, recv_buf_, stride_of(p), false);
  recv_total_ = 0;
  for (const std::int64_t c : recv_counts_)
    recv_total_ += static_cast<std::size_t>(c);
  unpack_append(p, recv_buf_, recv_total_);
  return recv_total_;
}

namespace {
constexpr int kForwardTag = 7302;
using Requests = std::vector<MPI_Request>;
} // namespace

std::vector<double> ParticleExchange::route(std::span<const int> dest,
                                            std::span<const double> records, int stride) {
  const int ranks = comm_.size();
  const auto st = static_cast<std::size_t>(stride);
  if (stride <= 0 || records.size() != dest.size() * st)
    throw std::invalid_argument("ParticleExchange::route: one destination per record");
  std::vector<std::int64_t> counts(static_cast<std::size_t>(ranks), 0);
  for (const int r : dest) {
    if (r < 0 || r >= ranks)
      throw std::invalid_argument("ParticleExchange::route: destination rank out of range");
    ++counts[static_cast<std::size_t>(r)];
  }
  // Pack by destination rank, each rank's in record order (a counting sort).
  std::vector<std::size_t> at(static_cast<std::size_t>(ranks) + 1, 0);
  for (int r = 0; r < ranks; ++r)
    at[r + 1] = at[r] + static_cast<std::size_t>(counts[r]) * st;
  std::vector<double> send(records.size());
  for (std::size_t q = 0; q < dest.size(); ++q) {
    std::size_t& o = at[static_cast<std::size_t>(dest[q])];
    std::copy_n(records.begin() + static_cast<std::ptrdiff_t>(q * st), st,
                send.begin() + static_cast<std::ptrdiff_t>(o));
    o += st;
  }
  std::vector<std::int64_t> recv_counts;
  std::vector<double> recv;
  exchange(counts, send, recv_counts, recv, stride, false);
  return recv;
}

void ParticleExchange::forward_begin(const ParticleStore& p) {
  const bool spin = p.rotation;
  fwd_stride_ = spin ? 9 : 6;
  const auto stride = static_cast<std::size_t>(fwd_stride_);
  fwd_send_.resize(plan_.size() * stride);
  double* out = fwd_send_.data();
  for (const Copy& c : plan_) {
    const std::size_t i = c.index;
    out[0] = p.x[i] + c.shift[0], out[1] = p.y[i] + c.shift[1], out[2] = p.z[i] + c.shift[2];
    out[3] = p.vx[i], out[4] = p.vy[i], out[5] = p.vz[i];
    if (spin)
      out[6] = p.wx[i], out[7] = p.wy[i], out[8] = p.wz[i];
    out += stride;
  }
  fwd_recv_.resize(recv_total_ * stride);
  const int ranks = comm_.size(), me = comm_.rank();
  if (!requests_)
    requests_ = std::make_shared<Requests>();
  auto& req = *static_cast<Requests*>(requests_.get());
  req.clear();
  std::size_t so = 0, ro = 0; // offsets in doubles; the plan and the arrivals are in rank order
  for (int r = 0; r < ranks; ++r) {
    const auto ns = static_cast<std::size_t>(send_counts_[r]) * stride;
    const auto nr = static_cast<std::size_t>(recv_counts_[r]) * stride;
    if (r == me) {
      std::copy(fwd_send_.begin() + static_cast<std::ptrdiff_t>(so),
                fwd_send_.begin() + static_cast<std::ptrdiff_t>(so + ns),
                fwd_recv_.begin() + static_cast<std::ptrdiff_t>(ro));
    } else {
      if (nr > 0)
        MPI_Irecv(fwd_recv_.data() + ro, static_cast<int>(nr), MPI_DOUBLE, r, kForwardTag,
                  mpi_comm(comm_), &req.emplace_back());
      if (ns > 0) {
        count_messages::point_to_point(static_cast<std::int64_t>(ns * sizeof(double)));
        MPI_Isend(fwd_send_.data() + so, static_cast<int>(ns), MPI_DOUBLE, r, kForwardTag,
                  mpi_comm(comm_), &req.emplace_back());
      }
    }
    so += ns, ro += nr;
  }
}

void ParticleExchange::forward_end(ParticleStore& p) {
  if (requests_) {
    auto& req = *static_cast<Requests*>(requests_.get());
    if (!req.empty()) {
      MpiWait w(comm_);
      MPI_Waitall(static_cast<int>(req.size()), req.data(), MPI_STATUSES_IGNORE);
      req.clear();
    }
  }
  const double* in = fwd_recv_.data();
  const bool spin = fwd_stride_ == 9;
  for (std::size_t g = owned_; g < owned_ + recv_total_; ++g, in += fwd_stride_) {
    p.x[g] = in[0], p.y[g] = in[1], p.z[g] = in[2];
    p.vx[g] = in[3], p.vy[g] = in[4], p.vz[g] = in[5];
    if (spin)
      p.wx[g] = in[6], p.wy[g] = in[7], p.wz[g] = in[8];
  }
}

void ParticleExchange::forward_columns(std::span<std::vector<double>* const> columns) {
  const auto stride = static_cast<int>(columns.size());
  for (const std::vector<double>* v : columns)
    if (v->size() != owned_ + recv_total_)
      throw std::invalid_argument("ParticleExchange::forward_columns: one value per particle");
  if (stride == 0)
    return;
  std::vector<double> send(plan_.size() * columns.size()), recv;
  double* out = send.data();
  for (const Copy& c : plan_)
    for (const std::vector<double>* v : columns)
      *out++ = (*v)[c.index];
  std::vector<std::int64_t> counts = recv_counts_;
  exchange(send_counts_, send, counts, recv, stride, true);
  const double* in = recv.data();
  for (std::size_t g = owned_; g < owned_ + recv_total_; ++g)
    for (std::vector<double>* v : columns)
      (*v)[g] = *in++;
}

} // namespace cfddem
