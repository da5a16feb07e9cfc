#include "apps/checkpoint.hpp"

#include <algorithm>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <exception>
#include <iterator>
#include <limits>
#include <string_view>
#include <vector>

#include <fmt/format.h>
#include <unistd.h>

#include "apps/run_output.hpp"
#include "core/error.hpp"
#include "core/hdf5_file.hpp"
#include "core/scene_keys.hpp"
#include "core/state_io.hpp"
#include "dem/scheme_checkpoint.hpp"

namespace cfddem::apps {

namespace {

constexpr std::int64_t kFormat = 1;

// FNV-1a over the bytes of every array, in the order written (and read).
struct Hash {
  std::uint64_t h = 1469598103934665603ULL;
  template <class T> void add(const std::vector<T>& v) {
    const auto* b = reinterpret_cast<const unsigned char*>(v.data());
    for (std::size_t i = 0; i < v.size() * sizeof(T); ++i)
      h = (h ^ b[i]) * 1099511628211ULL;
    const std::uint64_t n = v.size();
    for (int k = 0; k < 8; ++k)
      h = (h ^ ((n >> (8 * k)) & 0xff)) * 1099511628211ULL;
  }
};

// The checkpoint's side of a scheme's StateWriter and StateReader (core/state_io.hpp): arrays
// checksummed in the order put or read.
struct Writer final : StateWriter {
  explicit Writer(h5::File& file) : f(file) {}
  h5::File& f;
  Hash hash;
  template <class T> void put_array(const std::string& name, const std::vector<T>& v) {
    hash.add(v);
    f.write(name, std::span<const T>(v), {static_cast<hsize_t>(v.size())});
  }
  void group(const std::string& name) override { f.create_group(name); }
  void put(const std::string& name, const std::vector<double>& v) override { put_array(name, v); }
  void put(const std::string& name, const std::vector<std::int64_t>& v) override {
    put_array(name, v);
  }
  void put(const std::string& name, const std::vector<std::uint32_t>& v) override {
    put_array(name, v);
  }
  void attribute(const std::string& name, double v) override { f.attribute(name, v); }
  void attribute(const std::string& name, std::int64_t v) override { f.attribute(name, v); }
};

struct Reader final : StateReader {
  explicit Reader(const h5::File& file) : f(file) {}
  const h5::File& f;
  Hash hash;
  bool exists(const std::string& name) const override { return f.exists(name); }
  double attribute_double(const std::string& name) const override {
    return f.read_attribute_double(name);
  }
  std::int64_t attribute_int64(const std::string& name) const override {
    return f.read_attribute_int64(name);
  }
  std::vector<double> doubles(const std::string& name, std::size_t n) override {
    auto a = f.read_double(name);
    check(name, a.shape, n);
    hash.add(a.values);
    return std::move(a.values);
  }
  std::vector<std::int64_t> int64s(const std::string& name, std::size_t n) override {
    auto a = f.read_int64(name);
    check(name, a.shape, n);
    hash.add(a.values);
    return std::move(a.values);
  }
  std::vector<std::uint32_t> uint32s(const std::string& name, std::size_t n) override {
    auto a = f.read_uint32(name);
    check(name, a.shape, n);
    hash.add(a.values);
    return std::move(a.values);
  }
  void check(const std::string& name, const std::vector<hsize_t>& shape, std::size_t n) {
    if (shape.size() != 1 || (n != kAny && shape[0] != n))
      throw RunError(fmt::format("dataset '{}' has the wrong shape", name));
  }
};

std::vector<double> flatten_rows(const std::vector<std::vector<double>>& rows) {
  std::vector<double> v;
  for (const auto& r : rows)
    v.insert(v.end(), r.begin(), r.end());
  return v;
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (std::size_t i = 0; i < v.size(); ++i)
    s += (i ? "," : "") + v[i];
  return s;
}

// The gas solver's arrays, the coupling counters and the coupled loop's position (/gas).
void write_gas(h5::File& f, Writer& w, const Checkpoint& c) {
  const GasCoupling::State& g = c.gas_state;
  const CoupledLoopState& l = c.loop;
  w.put("/gas/counters",
        std::vector<std::int64_t>{g.gas_substeps, g.projection_iterations, g.projection_fallbacks,
                                  l.fluid_steps, l.row_pending ? 1 : 0, l.snapshot_pending ? 1 : 0,
                                  g.implicit_viscosity_steps, g.viscous_iterations, l.last_n_sub});
  const FluidDiagnostics& d = l.row_fluid;
  w.put("/gas/loop", std::vector<double>{g.last_dt, l.time, l.next_output, l.next_snapshot,
                                         l.dt_f_sum, l.row_time, d.pressure_drop, d.gas_momentum[0],
                                         d.gas_momentum[1], d.gas_momentum[2], d.mass_residual,
                                         g.drag_time});
  // Written once particles have entered or left (absent: none had, as in older checkpoints).
  if (l.particles_in > 0 || l.particles_out > 0)
    w.put("/gas/particle_flux",
          std::vector<double>{l.mass_in, l.mass_out, static_cast<double>(l.particles_in),
                              static_cast<double>(l.particles_out)});
  if (l.inlet.next_id >= 0) { // an inlet has started
    w.put("/gas/inlet", std::vector<double>{l.inlet.owed, static_cast<double>(l.inlet.drawn),
                                            static_cast<double>(l.inlet.next_id)});
    w.put("/gas/inlet_queue_radius", l.inlet.queue_radius);
    w.put("/gas/inlet_queue_mass", l.inlet.queue_mass);
  }
  w.put("/gas/held_force_x", l.held_force[0]);
  w.put("/gas/held_force_y", l.held_force[1]);
  w.put("/gas/held_force_z", l.held_force[2]);
  // The cell data of a snapshot waiting for its particle step (empty arrays otherwise).
  const CellFields& s = l.snapshot_cells;
  f.create_group("/gas/snapshot");
  w.put("/gas/snapshot/cells", std::vector<std::int64_t>(s.cells.begin(), s.cells.end()));
  w.put("/gas/snapshot/x_nodes", s.x_nodes);
  w.put("/gas/snapshot/y_nodes", s.y_nodes);
  w.put("/gas/snapshot/z_nodes", s.z_nodes);
  w.put("/gas/snapshot/eps_g", s.eps_g);
  w.put("/gas/snapshot/pressure", s.pressure);
  w.put("/gas/snapshot/gas_velocity", s.gas_velocity);
  // R ranks: each rank's gas box, lo then hi (6 values a box).
  if (!c.gas_boxes.empty()) {
    std::vector<std::int64_t> boxes;
    for (const CellBox& b : c.gas_boxes)
      for (const auto& v : {b.lo, b.hi})
        boxes.insert(boxes.end(), v.begin(), v.end());
    w.put("/gas/boxes", boxes);
  }
}

void read_gas(Reader& r, Checkpoint& c) {
  GasCoupling::State& g = c.gas_state;
  CoupledLoopState& l = c.loop;
  // 9 counters; older checkpoints hold 6 (before the implicit-viscosity count), 7 (before the
  // viscous iterations) or 8 (before the last fluid step's particle steps): the missing counts
  // restart from 0.
  const auto k = r.int64s("/gas/counters", StateReader::kAny);
  if (k.size() < 6 || k.size() > 9)
    throw RunError(fmt::format("checkpoint: /gas/counters holds {} values, expected 9 (or 6 to 8 "
                               "from an older checkpoint)",
                               k.size()));
  g.gas_substeps = k[0], g.projection_iterations = k[1], g.projection_fallbacks = k[2];
  l.fluid_steps = k[3], l.row_pending = k[4] != 0, l.snapshot_pending = k[5] != 0;
  g.implicit_viscosity_steps = k.size() >= 7 ? k[6] : 0;
  g.viscous_iterations = k.size() >= 8 ? k[7] : 0;
  l.last_n_sub = k.size() == 9 ? k[8] : 0;
  // 12 values; checkpoints before the adaptive step's drag time hold 11 (the restart then keeps
  // the drag time of the particles' deposit at set-up; a fixed fluid.dt never reads it).
  const auto q = r.doubles("/gas/loop", StateReader::kAny);
  if (q.size() != 11 && q.size() != 12)
    throw RunError(fmt::format("checkpoint: /gas/loop holds {} values, expected 12 (or 11 from "
                               "an older checkpoint)",
                               q.size()));
  if (q.size() == 12)
    g.drag_time = q[11];
  g.last_dt = q[0], l.time = q[1], l.next_output = q[2], l.next_snapshot = q[3];
  l.dt_f_sum = q[4], l.row_time = q[5];
  l.row_fluid = {q[6], {q[7], q[8], q[9]}, q[10]};
  // In the order written (the checksum runs over the arrays in that order).
  if (r.exists("/gas/particle_flux")) {
    const auto m = r.doubles("/gas/particle_flux", 4);
    l.mass_in = m[0], l.mass_out = m[1];
    l.particles_in = static_cast<std::int64_t>(m[2]), l.particles_out = static_cast<std::int64_t>(m[3]);
  }
  if (r.exists("/gas/inlet")) {
    const auto v = r.doubles("/gas/inlet", 3);
    l.inlet.owed = v[0], l.inlet.drawn = static_cast<std::int64_t>(v[1]);
    l.inlet.next_id = static_cast<std::int64_t>(v[2]);
    l.inlet.queue_radius = r.doubles("/gas/inlet_queue_radius", StateReader::kAny);
    l.inlet.queue_mass = r.doubles("/gas/inlet_queue_mass", l.inlet.queue_radius.size());
  }
  l.held_force[0] = r.doubles("/gas/held_force_x", c.particles.size());
  l.held_force[1] = r.doubles("/gas/held_force_y", c.particles.size());
  l.held_force[2] = r.doubles("/gas/held_force_z", c.particles.size());
  CellFields& s = l.snapshot_cells;
  const auto n = r.int64s("/gas/snapshot/cells", 3);
  s.cells = {n[0], n[1], n[2]};
  s.x_nodes = r.doubles("/gas/snapshot/x_nodes", StateReader::kAny);
  s.y_nodes = r.doubles("/gas/snapshot/y_nodes", StateReader::kAny);
  s.z_nodes = r.doubles("/gas/snapshot/z_nodes", StateReader::kAny);
  s.eps_g = r.doubles("/gas/snapshot/eps_g", StateReader::kAny);
  s.pressure = r.doubles("/gas/snapshot/pressure", s.eps_g.size());
  s.gas_velocity = r.doubles("/gas/snapshot/gas_velocity", 3 * s.eps_g.size());
  // R ranks leave the pending snapshot's cells out: the restart takes them from the gas restored.
  if (l.snapshot_pending && !s.eps_g.empty() &&
      (n[0] < 1 || n[1] < 1 || n[2] < 1 ||
       s.eps_g.size() != static_cast<std::size_t>(n[0] * n[1] * n[2]) ||
       s.x_nodes.size() != static_cast<std::size_t>(n[0] + 1) ||
       s.y_nodes.size() != static_cast<std::size_t>(n[1] + 1) ||
       s.z_nodes.size() != static_cast<std::size_t>(n[2] + 1)))
    throw RunError("the pending snapshot's cell data has the wrong shape");
  if (r.exists("/gas/boxes")) {
    const auto b = r.int64s("/gas/boxes", StateReader::kAny);
    if (b.size() % 6 != 0)
      throw RunError(fmt::format("/gas/boxes holds {} values, not 6 per box", b.size()));
    const auto in_int = [](std::int64_t v) {
      if (v < 0 || v > std::numeric_limits<int>::max())
        throw RunError(fmt::format("/gas/boxes holds the index {}", v));
      return static_cast<int>(v);
    };
    for (std::size_t i = 0; i < b.size(); i += 6) {
      CellBox box;
      for (std::size_t a = 0; a < 3; ++a) {
        box.lo[a] = in_int(b[i + a]);
        box.hi[a] = in_int(b[i + 3 + a]);
      }
      c.gas_boxes.push_back(box);
    }
  }
}

} // namespace

std::string restart_configuration(const Scene& scene) {
  std::string s;
  for (const auto& [k, v] : describe_scene(scene)) {
    if (k == "name" || k.rfind("run.", 0) == 0 || k.rfind("output.", 0) == 0)
      continue;
    s += k + " = " + v + "\n";
  }
  return s;
}

namespace {

// Everything but the gas grids into an open file; gas_sum: the gas grids' checksum.
void write_contents(h5::File& f, const Checkpoint& c, std::int64_t gas_sum) {
  const ParticleStore& p = c.particles;
  Writer w(f);
  f.attribute("format", kFormat);
  f.attribute("program", std::string("cfddem checkpoint"));
  f.attribute("scheme", c.scheme);
  f.attribute("dt", c.dt);
  f.attribute("step", c.step);
  f.attribute("last_row_step", c.last_row_step);
  f.attribute("configuration", c.configuration);
  f.attribute("columns", join(c.columns));
  f.attribute("particles", static_cast<std::int64_t>(p.size()));
  f.attribute("rotation", static_cast<std::int64_t>(p.rotation));
  f.attribute("rows", static_cast<std::int64_t>(c.rows.size()));
  f.create_group("/particles");
  for (const auto& [name, v] : {std::pair{"x", &p.x},
                                {"y", &p.y},
                                {"z", &p.z},
                                {"vx_half", &p.vx},
                                {"vy_half", &p.vy},
                                {"vz_half", &p.vz},
                                {"fx", &p.fx},
                                {"fy", &p.fy},
                                {"fz", &p.fz},
                                {"radius", &p.radius},
                                {"mass", &p.mass},
                                {"inv_mass", &p.inv_mass}})
    w.put(std::string("/particles/") + name, *v);
  w.put("/particles/id", p.id);
  if (p.rotation)
    for (const auto& [name, v] : {std::pair{"wx_half", &p.wx},
                                  {"wy_half", &p.wy},
                                  {"wz_half", &p.wz},
                                  {"tx", &p.tx},
                                  {"ty", &p.ty},
                                  {"tz", &p.tz},
                                  {"inv_inertia", &p.inv_inertia}})
      w.put(std::string("/particles/") + name, *v);
  // Each scheme writes its own state (dem/scheme_checkpoint.hpp); explicit's list and counters
  // are in every checkpoint.
  dem::save(w, c.scheme_state, p.id);
  if (c.gas) {
    write_gas(f, w, c);
    f.attribute("gas_checksum", gas_sum);
  }
  w.put("/diagnostics_rows", flatten_rows(c.rows));
  std::vector<std::int64_t> ss, sn, sl, sc;
  std::vector<double> st;
  for (const auto& e : c.snapshots) {
    ss.push_back(e.step), st.push_back(e.time), sn.push_back(e.particles),
        sl.push_back(e.leaf ? 1 : 0);
    sc.insert(sc.end(), e.cells.begin(), e.cells.end());
  }
  f.create_group("/snapshots");
  w.put("/snapshots/step", ss);
  w.put("/snapshots/time", st);
  w.put("/snapshots/particles", sn);
  w.put("/snapshots/leaf", sl);
  w.put("/snapshots/cells", sc);
  f.attribute("checksum", static_cast<std::int64_t>(w.hash.h));
}

void rename_into_place(const std::string& tmp, const std::string& path) {
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw RunError(fmt::format("cannot rename '{}' to '{}'", tmp, path));
  }
}

GasBlock whole_grid(const std::array<int, 3>& cells) {
  return {cells, CellBox{{0, 0, 0}, cells}};
}

} // namespace

void write_checkpoint(const std::string& path, const Checkpoint& c) {
  const std::string tmp = fmt::format("{}.tmp.{}", path, ::getpid());
  try {
    h5::File f = h5::File::create(tmp);
    GasChecksum sums{};
    if (c.gas) {
      f.create_group("/gas");
      sums = write_gas_grids(f, c.gas_state, whole_grid(c.gas_cells), false);
    }
    write_contents(f, c, combine_checksum(sums));
    f.close();
  } catch (...) {
    std::remove(tmp.c_str());
    throw;
  }
  rename_into_place(tmp, path);
}

void write_checkpoint(const std::string& path, const Checkpoint& c, const GasBlock& block,
                      const Communicator& comm) {
  if (comm.size() == 1)
    return write_checkpoint(path, c);
  const bool root = comm.rank() == 0;
  // One temporary name for all ranks (rank 0's pid). The gas grids first, collectively; then
  // rank 0 alone adds the rest to the closed file and renames it.
  const std::int64_t pid = comm.sum(root ? static_cast<std::int64_t>(::getpid()) : 0);
  const std::string tmp = fmt::format("{}.tmp.{}", path, pid);
  std::string error;
  GasChecksum sums{};
  try {
    h5::File f = h5::File::create_collective(tmp, comm);
    f.create_group("/gas");
    sums = write_gas_grids(f, c.gas_state, block, true);
    f.close();
  } catch (const std::exception& e) {
    error = e.what();
  }
  error = comm.agree_on_error(error.empty() ? comm.size() : comm.rank(), error);
  comm.sum(sums);
  if (root && error.empty()) {
    try {
      h5::File f = h5::File::open_write(tmp);
      write_contents(f, c, combine_checksum(sums));
      f.close();
      rename_into_place(tmp, path);
    } catch (const std::exception& e) {
      error = e.what();
    }
  }
  if (root && !error.empty())
    std::remove(tmp.c_str());
  error = comm.agree_on_error(0, error);
  if (!error.empty())
    throw RunError(
        fmt::format("writing checkpoint '{}' on {} ranks failed: {}", path, comm.size(), error));
}

namespace {

// Everything but the gas grids, its checksum verified; throws RunError.
Checkpoint read_contents(const h5::File& f) {
  Checkpoint c;
  std::string program;
  try {
    program = f.read_attribute_string("program");
  } catch (const RunError&) {
    // Not one of ours: the format check below names what is missing.
  }
  if (program == "cfddem")
    throw RunError("it is a particle snapshot (snapshot_<step>.h5), not a checkpoint: restart "
                   "from a checkpoint_<step>.h5, written when output.checkpoint_interval > 0");
  // A format this version cannot read is refused by number, so a user can tell an older or a
  // newer writer apart from a damaged file.
  if (const std::int64_t format = f.read_attribute_int64("format"); format != kFormat)
    throw RunError(fmt::format("checkpoint format version {}, this version reads format {}",
                               format, kFormat));
  Reader r(f);
  c.scheme = f.read_attribute_string("scheme");
  c.dt = f.read_attribute_double("dt");
  c.step = f.read_attribute_int64("step");
  c.last_row_step = f.read_attribute_int64("last_row_step");
  c.configuration = f.read_attribute_string("configuration");
  const std::string cols = f.read_attribute_string("columns");
  for (std::size_t a = 0; a <= cols.size();) {
    const std::size_t b = std::min(cols.find(',', a), cols.size());
    c.columns.push_back(cols.substr(a, b - a));
    a = b + 1;
  }
  const std::int64_t n64 = f.read_attribute_int64("particles");
  const std::int64_t nrows = f.read_attribute_int64("rows");
  if (n64 < 0 || nrows < 0 || c.step < 0)
    throw RunError("negative counts");
  const auto n = static_cast<std::size_t>(n64);
  ParticleStore& p = c.particles;
  p.x = r.doubles("/particles/x", n);
  p.y = r.doubles("/particles/y", n);
  p.z = r.doubles("/particles/z", n);
  p.vx = r.doubles("/particles/vx_half", n);
  p.vy = r.doubles("/particles/vy_half", n);
  p.vz = r.doubles("/particles/vz_half", n);
  p.fx = r.doubles("/particles/fx", n);
  p.fy = r.doubles("/particles/fy", n);
  p.fz = r.doubles("/particles/fz", n);
  p.radius = r.doubles("/particles/radius", n);
  p.mass = r.doubles("/particles/mass", n);
  p.inv_mass = r.doubles("/particles/inv_mass", n);
  p.id = r.int64s("/particles/id", n);
  p.rotation = f.read_attribute_int64("rotation") != 0;
  if (p.rotation) {
    p.wx = r.doubles("/particles/wx_half", n);
    p.wy = r.doubles("/particles/wy_half", n);
    p.wz = r.doubles("/particles/wz_half", n);
    p.tx = r.doubles("/particles/tx", n);
    p.ty = r.doubles("/particles/ty", n);
    p.tz = r.doubles("/particles/tz", n);
    p.inv_inertia = r.doubles("/particles/inv_inertia", n);
  }
  c.scheme_state = dem::restore_scheme(r, c.scheme, p.id);
  c.gas = f.exists("/gas");
  if (c.gas)
    read_gas(r, c);
  const auto flat =
      r.doubles("/diagnostics_rows", static_cast<std::size_t>(nrows) * c.columns.size());
  for (std::size_t i = 0; i < static_cast<std::size_t>(nrows); ++i)
    c.rows.emplace_back(flat.begin() + static_cast<std::ptrdiff_t>(i * c.columns.size()),
                        flat.begin() + static_cast<std::ptrdiff_t>((i + 1) * c.columns.size()));
  const auto ss = r.int64s("/snapshots/step", StateReader::kAny);
  const auto st = r.doubles("/snapshots/time", ss.size());
  const auto sn = r.int64s("/snapshots/particles", ss.size());
  const auto sl = r.int64s("/snapshots/leaf", ss.size());
  // Checkpoints written before snapshots had cells lack the dataset (and did not hash it).
  const auto sc = f.exists("/snapshots/cells") ? r.int64s("/snapshots/cells", 3 * ss.size())
                                               : std::vector<std::int64_t>(3 * ss.size(), 0);
  for (std::size_t i = 0; i < ss.size(); ++i)
    c.snapshots.push_back({ss[i],
                           st[i],
                           sn[i],
                           sl[i] != 0,
                           {sc[3 * i], sc[3 * i + 1], sc[3 * i + 2]},
                           fmt::format("snapshot_{:09d}.h5", ss[i])});
  if (static_cast<std::uint64_t>(f.read_attribute_int64("checksum")) != r.hash.h)
    throw RunError("checksum mismatch: the arrays are corrupt");
  return c;
}

} // namespace

Checkpoint read_checkpoint(const std::string& path) {
  try {
    const h5::File f = h5::File::open_read(path);
    Checkpoint c = read_contents(f);
    if (c.gas) {
      c.gas_cells = gas_grid_cells(f);
      GasChecksum sums{};
      read_gas_grids(f, whole_grid(c.gas_cells), c.gas_state, sums);
      if (combine_checksum(sums) != f.read_attribute_int64("gas_checksum"))
        throw RunError("checksum mismatch: the gas fields are corrupt");
    }
    return c;
  } catch (const RunError& e) {
    throw ConfigError(fmt::format("checkpoint '{}'", path),
                      fmt::format("cannot restart: {}", e.what()));
  } catch (const std::exception& e) { // e.g. bad_alloc from absurd sizes in a corrupt file
    throw ConfigError(fmt::format("checkpoint '{}'", path),
                      fmt::format("cannot restart: corrupt file ({})", e.what()));
  }
}

namespace {

// Whether `boxes` are `parts` non-empty boxes that together cover the grid of `cells` once.
bool tile(const std::vector<CellBox>& boxes, const std::array<int, 3>& cells, int parts) {
  if (boxes.size() != static_cast<std::size_t>(parts))
    return false;
  std::int64_t covered = 0;
  for (std::size_t i = 0; i < boxes.size(); ++i) {
    const CellBox& b = boxes[i];
    for (int a = 0; a < 3; ++a)
      if (b.lo[a] < 0 || b.hi[a] > cells[a] || b.hi[a] <= b.lo[a])
        return false;
    for (std::size_t j = 0; j < i; ++j) {
      bool apart = false;
      for (int a = 0; a < 3; ++a)
        apart = apart || b.hi[a] <= boxes[j].lo[a] || boxes[j].hi[a] <= b.lo[a];
      if (!apart)
        return false;
    }
    covered += b.count();
  }
  return covered == static_cast<std::int64_t>(cells[0]) * cells[1] * cells[2];
}

} // namespace

Checkpoint read_checkpoint(const std::string& path, const GasBlock& block,
                           const Communicator& comm) {
  if (comm.size() == 1)
    return read_checkpoint(path);
  Checkpoint c;
  GasChecksum sums{};
  std::int64_t stored = 0;
  std::string error;
  try {
    const h5::File f = h5::File::open_read(path);
    c = read_contents(f);
    if (c.gas) {
      c.gas_cells = block.cells;
      // The boxes the writing run's gas had, where they cut this grid into this many boxes: the
      // restart goes on from them (bitwise), else from the count cut (`block`, to round-off).
      if (!tile(c.gas_boxes, block.cells, comm.size()))
        c.gas_boxes.clear();
      const GasBlock from =
          c.gas_boxes.empty()
              ? block
              : GasBlock{block.cells, c.gas_boxes[static_cast<std::size_t>(comm.rank())]};
      read_gas_grids(f, from, c.gas_state, sums);
      stored = f.read_attribute_int64("gas_checksum");
    }
  } catch (const RunError& e) {
    error = e.what();
  } catch (const std::exception& e) {
    error = fmt::format("corrupt file ({})", e.what());
  }
  error = comm.agree_on_error(error.empty() ? comm.size() : comm.rank(), error);
  if (error.empty()) {
    comm.sum(sums); // every rank's owned points: the whole grid's sum
    if (c.gas && combine_checksum(sums) != stored)
      error = "checksum mismatch: the gas fields are corrupt";
  }
  if (!error.empty())
    throw ConfigError(fmt::format("checkpoint '{}'", path),
                      fmt::format("cannot restart: {}", error));
  return c;
}

namespace {

// Keys added after checkpoints of this format were written, at the value that older runs had
// without naming it: such a line is left out, so those checkpoints still restart at it. (Older
// runs had no orb global mode: their checkpoints restart with its default, which changes no bit
// where it never triggers, as a new version continues any run with its own arithmetic;
// dem.orb_global = false continues the leaf steps but is refused with an older checkpoint. Orb
// on R ranks had no global mode before dem.orb_global_min_per_rank: its R-rank checkpoints
// restart at the default, global where nearly every leaf is fine and the ranks hold enough
// particles, as a new run would be.)
constexpr std::string_view kImpliedLines[] = {
    "fluid.coupling = \"two_way\"",  "fluid.projections = 2",
    "fluid.advection = \"mol\"",     "particles.outflow = \"remove\"",
    "dem.orb_global = true",         "dem.orb_global_min_per_rank = 10000",
    "fluid.viscous_step = \"solve\""};

// A configuration value as a reader would write it: each number in the shortest form that reads
// back the same. The lines hold 17 digits, so that a restart compares them exactly, and a
// refusal showed "fluid.dt = 5.0000000000000002e-05 here" for a typed 5e-5.
std::string shown(std::string_view value) {
  std::string out;
  std::size_t i = 0;
  while (i < value.size()) {
    std::size_t j = i;
    while (j < value.size() && std::string_view("[], ").find(value[j]) == std::string_view::npos)
      ++j;
    if (j == i) {
      out.push_back(value[i++]);
      continue;
    }
    const std::string_view token = value.substr(i, j - i);
    double x = 0.0;
    const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), x);
    if (ec == std::errc() && end == token.data() + token.size())
      out += fmt::format("{}", x);
    else
      out.append(token);
    i = j;
  }
  return out;
}

// Every key whose line differs between this run's fixed lines and the checkpoint's, in this
// run's order: both values, or the value an older checkpoint implies for a key it predates
// (kImpliedLines), so that a user sees all that must change at once.
std::string configuration_differences(const std::string& now, const std::string& then) {
  const auto key_of = [](std::string_view line) { return line.substr(0, line.find(" = ")); };
  const auto value_of = [](std::string_view line) {
    const std::size_t eq = line.find(" = ");
    return shown(eq == std::string_view::npos ? std::string_view() : line.substr(eq + 3));
  };
  const auto line_shown = [&](std::string_view line) {
    return fmt::format("{} = {}", key_of(line), value_of(line));
  };
  const auto lines_of = [](const std::string& text) {
    std::vector<std::string_view> lines;
    for (std::size_t pos = 0; pos < text.size();) {
      const std::size_t end = std::min(text.find('\n', pos), text.size());
      if (end > pos)
        lines.emplace_back(text.data() + pos, end - pos);
      pos = end + 1;
    }
    return lines;
  };
  const std::vector<std::string_view> here = lines_of(now), there = lines_of(then);
  const auto find = [&](const std::vector<std::string_view>& in, std::string_view key) {
    return std::ranges::find_if(in, [&](std::string_view l) { return key_of(l) == key; });
  };
  // The implied line of a key (kImpliedLines), or its end.
  const auto implied_line = [&](std::string_view key) {
    return std::ranges::find_if(kImpliedLines,
                                [&](std::string_view l) { return key_of(l) == key; });
  };
  std::vector<std::string> out;
  for (const std::string_view line : here) {
    const std::string_view key = key_of(line);
    const auto it = find(there, key);
    if (it == there.end()) {
      const auto implied = implied_line(key);
      out.push_back(implied != std::end(kImpliedLines)
                        ? fmt::format("{} here; the checkpoint predates the key and ran {}",
                                      line_shown(line), line_shown(*implied))
                        : fmt::format("{} here; the checkpoint has no {}", line_shown(line), key));
    } else if (*it != line) {
      out.push_back(fmt::format("{} here, {} in the checkpoint", line_shown(line), value_of(*it)));
    }
  }
  for (const std::string_view line : there)
    if (find(here, key_of(line)) == here.end()) {
      // A key this run left out because it is at its implied value, or one this version lacks.
      const auto implied = implied_line(key_of(line));
      out.push_back(
          implied != std::end(kImpliedLines)
              ? fmt::format("{} here, {} in the checkpoint", line_shown(*implied), value_of(line))
              : fmt::format("{} in the checkpoint, unknown to this version", line_shown(line)));
    }
  std::string all;
  for (const std::string& d : out)
    all += (all.empty() ? "" : "; ") + d;
  return all.empty() ? std::string("the lines' order") : all;
}

// The configuration lines that must match at a restart: all but those of the keys a restart may
// change (restart_free_keys(), core/scene_keys.hpp: the gas drive, so that a bed settled with
// the gas at rest continues with the gas turned on) and the implied lines.
std::string restart_fixed_lines(const std::string& configuration) {
  std::string kept;
  std::size_t pos = 0;
  while (pos < configuration.size()) {
    std::size_t end = configuration.find('\n', pos);
    if (end == std::string::npos)
      end = configuration.size();
    const std::string_view line(configuration.data() + pos, end - pos);
    const bool free = restart_may_change(line.substr(0, line.find(" = "))) ||
                      std::ranges::find(kImpliedLines, line) != std::end(kImpliedLines);
    if (!free)
      kept.append(line).push_back('\n');
    pos = end + 1;
  }
  return kept;
}

// A checkpoint written before the mass balance columns: its columns and rows gain particle_mass
// (NaN: not recorded then), mass_in and mass_out (0: no particle could enter or leave then).
void upgrade_columns(Checkpoint& ck) {
  const std::size_t k = kColumnsBeforeMassBalance;
  if (ck.columns.size() < k || !std::equal(kBaseColumns.begin(), kBaseColumns.begin() + k,
                                           ck.columns.begin()) ||
      (ck.columns.size() > k && ck.columns[k] == kBaseColumns[k]))
    return;
  const auto at = static_cast<std::ptrdiff_t>(k);
  ck.columns.insert(ck.columns.begin() + at, kBaseColumns.begin() + at, kBaseColumns.begin() + at + 3);
  for (auto& r : ck.rows)
    if (r.size() >= k)
      r.insert(r.begin() + at, {std::numeric_limits<double>::quiet_NaN(), 0.0, 0.0});
}

// The checks of a checkpoint against the scene it restarts; throws ConfigError naming the file.
void check_fits(const Scene& scene, const std::string& path, const Checkpoint& ck) {
  if (ck.gas != scene.fluid.enabled)
    throw ConfigError(path, ck.gas ? "the checkpoint holds a gas state (written by a scene with "
                                     "a [fluid] table) but this scene has no gas"
                                   : "the checkpoint holds no gas state (written by a scene "
                                     "without a [fluid] table) but this scene has a [fluid] "
                                     "table: a gas cannot be added at a restart. To fluidize a "
                                     "settled bed, settle it with the gas at rest (the same "
                                     "[fluid] table, walls and no inflow), then restart it with "
                                     "the gas drive changed (fluid.inflow_velocity, fluid.bc.*; "
                                     "docs/hostile_input.md)");
  if (ck.scheme != scene.dem.scheme)
    throw ConfigError(path, fmt::format("checkpoint of scheme \"{}\", the scene runs \"{}\"",
                                        ck.scheme, scene.dem.scheme));
  if (ck.columns != diagnostics_columns(scene.output.contact_census)) {
    const bool census_then = ck.columns == diagnostics_columns(true);
    if (census_then || ck.columns == diagnostics_columns(false))
      throw ConfigError(path, fmt::format("the checkpoint was written with "
                                          "output.contact_census = {}, this run has {}: set it "
                                          "as the run that wrote it did",
                                          census_then, !census_then));
    throw ConfigError(path, "checkpoint diagnostics columns differ from this version's");
  }
  const std::string now = restart_fixed_lines(restart_configuration(scene));
  const std::string then = restart_fixed_lines(ck.configuration);
  if (then != now)
    throw ConfigError(path, fmt::format("the checkpoint was written with a different "
                                        "configuration: {} (only {} may change at a restart)",
                                        configuration_differences(now, then),
                                        restart_free_keys_text(false)));
}

} // namespace

Checkpoint load_checkpoint(const Scene& scene, const std::string& path) {
  Checkpoint ck = read_checkpoint(path);
  ck.gas_boxes.clear(); // one rank: one box, the whole grid
  upgrade_columns(ck);
  check_fits(scene, path, ck);
  return ck;
}

Checkpoint load_checkpoint(const Scene& scene, const std::string& path, const GasBlock& block,
                           const Communicator& comm) {
  Checkpoint ck = read_checkpoint(path, block, comm);
  upgrade_columns(ck);
  check_fits(scene, path, ck); // the same file on every rank: the same error
  return ck;
}

Checkpoint checkpoint_header(const Scene& scene, const std::string& scheme, double dt,
                             std::int64_t step, std::int64_t last_row_step,
                             const std::vector<std::vector<double>>& rows,
                             const std::vector<SnapshotEntry>& snapshots) {
  Checkpoint c;
  c.scheme = scheme;
  c.dt = dt;
  c.step = step;
  c.last_row_step = last_row_step;
  c.columns = diagnostics_columns(scene.output.contact_census);
  c.rows = rows;
  c.snapshots = snapshots;
  c.configuration = restart_configuration(scene);
  return c;
}

} // namespace cfddem::apps
