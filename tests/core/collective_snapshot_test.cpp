// Snapshots written collectively with parallel HDF5 (core/particle_snapshot.hpp): run under
// mpirun with 1, 2 and 3 ranks, each rank holding every R-th particle; the file holds every
// particle exactly once with its values, whatever the rank count.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <unistd.h>
#include <vector>

#include <gtest/gtest.h>
#include <mpi.h>

#include "core/hdf5_file.hpp"
#include "core/particle_snapshot.hpp"

using namespace cfddem;

namespace {

int rank_of() {
  int r = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &r);
  return r;
}
int ranks_of() {
  int r = 1;
  MPI_Comm_size(MPI_COMM_WORLD, &r);
  return r;
}

// A value of particle `id` and component c that no other (id, c) shares.
double value(std::int64_t id, int c) { return 1e-3 * static_cast<double>(id) + 0.1 * c + 0.01; }

} // namespace

TEST(CollectiveSnapshot, EveryParticleOnceWithItsValues) {
  const int rank = rank_of(), ranks = ranks_of();
  constexpr std::int64_t kTotal = 101;
  std::vector<double> x, y, z, vx, vy, vz, radius, mass;
  std::vector<std::int64_t> id, leaf;
  for (std::int64_t i = rank; i < kTotal; i += ranks) {
    id.push_back(i), leaf.push_back(i % 7);
    x.push_back(value(i, 0)), y.push_back(value(i, 1)), z.push_back(value(i, 2));
    vx.push_back(value(i, 3)), vy.push_back(value(i, 4)), vz.push_back(value(i, 5));
    radius.push_back(5e-5), mass.push_back(1e-9);
  }
  // One directory for all ranks, made by rank 0.
  std::string dir;
  if (rank == 0) {
    dir = (std::filesystem::temp_directory_path() /
           ("cfddem_collective_" + std::to_string(::getpid())))
              .string();
    std::filesystem::create_directories(dir);
  }
  int len = static_cast<int>(dir.size());
  MPI_Bcast(&len, 1, MPI_INT, 0, MPI_COMM_WORLD);
  dir.resize(static_cast<std::size_t>(len));
  MPI_Bcast(dir.data(), len, MPI_CHAR, 0, MPI_COMM_WORLD);

  SnapshotFields f;
  f.time = 0.5, f.step = 7, f.dt = 1e-7;
  f.x = x, f.y = y, f.z = z, f.vx = vx, f.vy = vy, f.vz = vz, f.radius = radius, f.mass = mass;
  f.id = id, f.leaf = leaf;
  const SnapshotEntry e = write_particle_snapshot(dir, f, MPI_COMM_WORLD);
  EXPECT_EQ(e.particles, kTotal);
  EXPECT_TRUE(e.leaf);
  MPI_Barrier(MPI_COMM_WORLD);
  if (rank == 0) {
    const h5::File file = h5::File::open_read((std::filesystem::path(dir) / e.file).string());
    const auto ids = file.read_int64("/particles/id");
    const auto pos = file.read_double("/particles/position");
    const auto vel = file.read_double("/particles/velocity");
    const auto lf = file.read_int64("/particles/leaf");
    ASSERT_EQ(ids.values.size(), static_cast<std::size_t>(kTotal));
    ASSERT_EQ(pos.shape, (std::vector<hsize_t>{kTotal, 3}));
    std::vector<int> seen(kTotal, 0);
    for (std::size_t k = 0; k < ids.values.size(); ++k) {
      const std::int64_t i = ids.values[k];
      ASSERT_GE(i, 0);
      ASSERT_LT(i, kTotal);
      ++seen[static_cast<std::size_t>(i)];
      for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(pos.values[3 * k + static_cast<std::size_t>(c)], value(i, c));
        EXPECT_EQ(vel.values[3 * k + static_cast<std::size_t>(c)], value(i, 3 + c));
      }
      EXPECT_EQ(lf.values[k], i % 7);
    }
    EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](int s) { return s == 1; }));
    EXPECT_DOUBLE_EQ(file.read_attribute_double("time"), 0.5);
    // No temporary file left behind.
    int files = 0;
    for (const auto& entry : std::filesystem::directory_iterator(dir)) ++files, (void)entry;
    EXPECT_EQ(files, 1);
    std::filesystem::remove_all(dir);
  }
}
