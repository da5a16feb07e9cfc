#include "core/particle_snapshot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include <fmt/format.h>
#include <unistd.h>

#include "core/atomic_file.hpp"
#include "core/communicator_mpi.hpp"
#include "core/error.hpp"
#include "core/hdf5_file.hpp"

namespace cfddem {

namespace {

void write_cells(h5::File& file, const CellFields& c) {
  const auto [nx, ny, nz] = c.cells;
  const auto h = [](std::int64_t v) { return static_cast<hsize_t>(v); };
  file.create_group("/fluid");
  file.write("/fluid/x_nodes", std::span<const double>(c.x_nodes), {h(nx + 1)});
  file.write("/fluid/y_nodes", std::span<const double>(c.y_nodes), {h(ny + 1)});
  file.write("/fluid/z_nodes", std::span<const double>(c.z_nodes), {h(nz + 1)});
  file.write("/fluid/eps_g", std::span<const double>(c.eps_g), {h(nz), h(ny), h(nx)});
  file.write("/fluid/pressure", std::span<const double>(c.pressure), {h(nz), h(ny), h(nx)});
  file.write("/fluid/gas_velocity", std::span<const double>(c.gas_velocity),
             {h(nz), h(ny), h(nx), 3});
}

// The collective counterpart of write_cells: every rank its block of cells, rank 0 the nodes.
void write_cell_blocks(h5::File& file, const CellFields& c, int rank) {
  const auto h = [](std::int64_t v) { return static_cast<hsize_t>(v); };
  const auto [nx, ny, nz] = c.cells;
  const bool whole = c.block_cells == std::array<std::int64_t, 3>{};
  const auto lo = c.block_lo;
  const auto n = whole ? c.cells : c.block_cells;
  file.create_group("/fluid");
  const std::vector<double>* nodes[3] = {&c.x_nodes, &c.y_nodes, &c.z_nodes};
  const char* names[3] = {"/fluid/x_nodes", "/fluid/y_nodes", "/fluid/z_nodes"};
  for (int a = 0; a < 3; ++a) {
    const std::span<const double> mine =
        rank == 0 ? std::span<const double>(*nodes[a]) : std::span<const double>();
    file.write_rows(names[a], mine, h(c.cells[a] + 1), 0, 1);
  }
  const std::vector<hsize_t> shape = {h(nz), h(ny), h(nx)};
  const std::vector<hsize_t> start = {h(lo[2]), h(lo[1]), h(lo[0])};
  const std::vector<hsize_t> count = {h(n[2]), h(n[1]), h(n[0])};
  file.write_block("/fluid/eps_g", c.eps_g, shape, start, count);
  file.write_block("/fluid/pressure", c.pressure, shape, start, count);
  file.write_block("/fluid/gas_velocity", c.gas_velocity, {h(nz), h(ny), h(nx), 3},
                   {start[0], start[1], start[2], 0}, {count[0], count[1], count[2], 3});
}

std::string data_item(const SnapshotEntry& e, const std::string& dataset, const std::string& dims,
                      const char* type) {
  return fmt::format("      <DataItem Dimensions=\"{}\" NumberType=\"{}\" Precision=\"8\" "
                     "Format=\"HDF\">{}:{}</DataItem>\n",
                     dims, type, e.file, dataset);
}

std::string attribute(const std::string& name, bool vector, const char* center,
                      const std::string& item) {
  return fmt::format("    <Attribute Name=\"{}\" AttributeType=\"{}\" Center=\"{}\">\n{}"
                     "    </Attribute>\n",
                     name, vector ? "Vector" : "Scalar", center, item);
}

// The fluid of one snapshot as a rectilinear grid (XDMF 2's 3DRectMesh with VXVYVZ node
// coordinates: unambiguous axis order, unlike ORIGIN_DXDYDZ whose order readers disagree on).
std::string fluid_grid(const SnapshotEntry& e) {
  const auto [nx, ny, nz] = e.cells;
  const std::string cells = fmt::format("{} {} {}", nz, ny, nx);
  std::string s = fmt::format("   <Grid Name=\"fluid_step_{}\" GridType=\"Uniform\">\n", e.step);
  s += fmt::format("    <Time Value=\"{:.17g}\"/>\n", e.time);
  s += fmt::format("    <Topology TopologyType=\"3DRectMesh\" Dimensions=\"{} {} {}\"/>\n",
                   nz + 1, ny + 1, nx + 1);
  s += "    <Geometry GeometryType=\"VXVYVZ\">\n" +
       data_item(e, "/fluid/x_nodes", std::to_string(nx + 1), "Float") +
       data_item(e, "/fluid/y_nodes", std::to_string(ny + 1), "Float") +
       data_item(e, "/fluid/z_nodes", std::to_string(nz + 1), "Float") + "    </Geometry>\n";
  s += attribute("eps_g", false, "Cell", data_item(e, "/fluid/eps_g", cells, "Float"));
  s += attribute("pressure", false, "Cell", data_item(e, "/fluid/pressure", cells, "Float"));
  s += attribute("gas_velocity", true, "Cell",
                 data_item(e, "/fluid/gas_velocity", cells + " 3", "Float"));
  return s + "   </Grid>\n";
}

} // namespace

namespace {

// Per-particle rows of a snapshot: position and velocity triples, diameter, speed, kinetic
// energy, local step.
struct SnapshotRows {
  std::vector<double> pos, vel, diam, speed, ke, dt;
  explicit SnapshotRows(const SnapshotFields& f) {
    const std::size_t n = f.x.size();
    pos.resize(3 * n), vel.resize(3 * n), diam.resize(n), speed.resize(n), ke.resize(n), dt.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      pos[3 * i] = f.x[i], pos[3 * i + 1] = f.y[i], pos[3 * i + 2] = f.z[i];
      vel[3 * i] = f.vx[i], vel[3 * i + 1] = f.vy[i], vel[3 * i + 2] = f.vz[i];
      diam[i] = 2.0 * f.radius[i];
      const double v2 = f.vx[i] * f.vx[i] + f.vy[i] * f.vy[i] + f.vz[i] * f.vz[i];
      speed[i] = std::sqrt(v2);
      ke[i] = 0.5 * f.mass[i] * v2;
      dt[i] = f.local_dt.empty() ? f.dt : f.local_dt[i];
    }
  }
};

} // namespace

SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f) {
  namespace fs = std::filesystem;
  const std::size_t n = f.x.size();
  SnapshotEntry e;
  e.step = f.step;
  e.time = f.time;
  e.particles = static_cast<std::int64_t>(n);
  e.leaf = !f.leaf.empty();
  e.file = fmt::format("snapshot_{:09d}.h5", f.step);
  const std::string path = (fs::path(dir) / e.file).string();
  const std::string tmp = fmt::format("{}.tmp.{}", path, ::getpid());

  const SnapshotRows r(f);
  const auto& [pos, vel, diam, speed, ke, dt] = r;
  const hsize_t hn = n;
  try {
    h5::File file = h5::File::create(tmp);
    file.attribute("time", f.time);
    file.attribute("step", f.step);
    file.attribute("program", std::string("cfddem"));
    file.create_group("/particles");
    file.write("/particles/position", std::span<const double>(pos), {hn, 3});
    file.write("/particles/velocity", std::span<const double>(vel), {hn, 3});
    file.write("/particles/diameter", std::span<const double>(diam), {hn});
    file.write("/particles/speed", std::span<const double>(speed), {hn});
    file.write("/particles/kinetic_energy", std::span<const double>(ke), {hn});
    file.write("/particles/local_dt", std::span<const double>(dt), {hn});
    file.write("/particles/id", f.id, {hn});
    if (e.leaf) file.write("/particles/leaf", f.leaf, {hn});
    if (f.cells) write_cells(file, *f.cells), e.cells = f.cells->cells;
    file.close();
  } catch (...) {
    std::remove(tmp.c_str());
    throw;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw RunError(fmt::format("cannot rename '{}' to '{}'", tmp, path));
  }
  return e;
}

SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f,
                                      MPI_Comm comm) {
  namespace fs = std::filesystem;
  int rank = 0, ranks = 1;
  MPI_Comm_rank(comm, &rank);
  MPI_Comm_size(comm, &ranks);
  if (ranks == 1) return write_particle_snapshot(dir, f);
  int has_cells = f.cells ? 1 : 0, all_cells = 0, any_cells = 0;
  MPI_Allreduce(&has_cells, &all_cells, 1, MPI_INT, MPI_MIN, comm);
  MPI_Allreduce(&has_cells, &any_cells, 1, MPI_INT, MPI_MAX, comm);
  if (all_cells != any_cells)
    throw RunError("a snapshot with cell data needs the cells of every rank");
  const auto local = static_cast<long long>(f.x.size());
  long long offset = 0, total = 0;
  MPI_Exscan(&local, &offset, 1, MPI_LONG_LONG, MPI_SUM, comm);
  if (rank == 0) offset = 0; // MPI_Exscan leaves rank 0's result undefined
  MPI_Allreduce(&local, &total, 1, MPI_LONG_LONG, MPI_SUM, comm);
  int has_leaf = f.leaf.empty() ? 0 : 1, all_leaf = 0;
  MPI_Allreduce(&has_leaf, &all_leaf, 1, MPI_INT, MPI_MIN, comm);
  SnapshotEntry e;
  e.step = f.step;
  e.time = f.time;
  e.particles = total;
  e.leaf = all_leaf != 0;
  e.file = fmt::format("snapshot_{:09d}.h5", f.step);
  const std::string path = (fs::path(dir) / e.file).string();
  // One temporary name for all ranks (rank 0's pid), renamed by rank 0 once all have written.
  long long pid = rank == 0 ? static_cast<long long>(::getpid()) : 0;
  MPI_Bcast(&pid, 1, MPI_LONG_LONG, 0, comm);
  const std::string tmp = fmt::format("{}.tmp.{}", path, pid);
  const SnapshotRows r(f);
  const auto h = [](long long v) { return static_cast<hsize_t>(v); };
  int ok = 1;
  std::string what;
  try {
    h5::File file = h5::File::create_collective(tmp, comm);
    file.attribute("time", f.time);
    file.attribute("step", f.step);
    file.attribute("program", std::string("cfddem"));
    file.create_group("/particles");
    file.write_rows("/particles/position", std::span<const double>(r.pos), h(total), h(offset), 3);
    file.write_rows("/particles/velocity", std::span<const double>(r.vel), h(total), h(offset), 3);
    file.write_rows("/particles/diameter", std::span<const double>(r.diam), h(total), h(offset), 1);
    file.write_rows("/particles/speed", std::span<const double>(r.speed), h(total), h(offset), 1);
    file.write_rows("/particles/kinetic_energy", std::span<const double>(r.ke), h(total), h(offset), 1);
    file.write_rows("/particles/local_dt", std::span<const double>(r.dt), h(total), h(offset), 1);
    file.write_rows("/particles/id", f.id, h(total), h(offset), 1);
    if (e.leaf) file.write_rows("/particles/leaf", f.leaf, h(total), h(offset), 1);
    if (all_cells) write_cell_blocks(file, *f.cells, rank), e.cells = f.cells->cells;
    file.close();
  } catch (const std::exception& ex) {
    ok = 0, what = ex.what();
  }
  int all_ok = 0;
  MPI_Allreduce(&ok, &all_ok, 1, MPI_INT, MPI_MIN, comm);
  if (rank == 0) {
    if (!all_ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
      std::remove(tmp.c_str());
      all_ok = 0;
    }
  }
  MPI_Bcast(&all_ok, 1, MPI_INT, 0, comm);
  if (!all_ok)
    throw RunError(fmt::format("writing snapshot '{}' on {} ranks failed{}", path, ranks,
                               what.empty() ? std::string() : ": " + what));
  return e;
}

std::string xdmf_index(const std::vector<SnapshotEntry>& entries) {
  std::string s = "<?xml version=\"1.0\" ?>\n<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n"
                  "<Xdmf Version=\"2.0\">\n <Domain>\n"
                  "  <Grid Name=\"particles\" GridType=\"Collection\" "
                  "CollectionType=\"Temporal\">\n";
  for (const auto& e : entries) {
    const auto item = [&](const std::string& name, const std::string& dims, const char* type) {
      return data_item(e, "/particles/" + name, dims, type);
    };
    const std::string n = std::to_string(e.particles), n3 = n + " 3";
    s += fmt::format("   <Grid Name=\"step_{}\" GridType=\"Uniform\">\n", e.step);
    s += fmt::format("    <Time Value=\"{:.17g}\"/>\n", e.time);
    s += fmt::format("    <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"{}\" "
                     "NodesPerElement=\"1\"/>\n",
                     n);
    s += "    <Geometry GeometryType=\"XYZ\">\n" + item("position", n3, "Float") +
         "    </Geometry>\n";
    const auto attr = [&](const std::string& name, bool vector, const char* type) {
      return attribute(name, vector, "Node", item(name, vector ? n3 : n, type));
    };
    s += attr("velocity", true, "Float");
    s += attr("diameter", false, "Float");
    s += attr("speed", false, "Float");
    s += attr("kinetic_energy", false, "Float");
    s += attr("local_dt", false, "Float");
    s += attr("id", false, "Int");
    if (e.leaf) s += attr("leaf", false, "Int");
    s += "   </Grid>\n";
  }
  // The gas: a second time series next to the particles (ParaView shows both as blocks).
  const auto has_cells = [](const SnapshotEntry& e) { return e.cells[0] > 0; };
  if (std::any_of(entries.begin(), entries.end(), has_cells)) {
    s += "  </Grid>\n  <Grid Name=\"fluid\" GridType=\"Collection\" "
         "CollectionType=\"Temporal\">\n";
    for (const auto& e : entries)
      if (has_cells(e)) s += fluid_grid(e);
  }
  s += "  </Grid>\n </Domain>\n</Xdmf>\n";
  return s;
}

void SnapshotIndex::add(const SnapshotEntry& e) {
  entries_.push_back(e);
  write_file_atomically((std::filesystem::path(dir_) / "snapshots.xmf").string(),
                        xdmf_index(entries_));
}

void SnapshotIndex::restore(const std::vector<SnapshotEntry>& entries) {
  entries_.clear();
  for (const auto& e : entries)
    if (std::filesystem::exists(std::filesystem::path(dir_) / e.file)) entries_.push_back(e);
}

SnapshotEntry write_particle_snapshot(const std::string& dir, const SnapshotFields& f,
                                      const Communicator& comm) {
  if (comm.size() == 1) return write_particle_snapshot(dir, f);
  return write_particle_snapshot(dir, f, mpi_comm(comm));
}

} // namespace cfddem
