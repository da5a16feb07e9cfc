#include "core/scene.hpp"

#include <cmath>
#include <filesystem>

#include <fmt/format.h>

#include "core/error.hpp"

namespace cfddem {

namespace {

void require(bool ok, const std::string& key, const std::string& why) {
  if (!ok)
    throw ConfigError(fmt::format("scene key '{}'", key), why);
}

double positive(SceneConfig& c, const std::string& key) {
  const double v = c.require_double(key);
  require(std::isfinite(v) && v > 0.0, key, fmt::format("must be > 0, got {}", v));
  return v;
}

double unit_interval(SceneConfig& c, const std::string& key, double fallback) {
  const double v = c.get_double(key, fallback);
  require(std::isfinite(v) && v >= 0.0 && v <= 1.0, key,
          fmt::format("must be in [0, 1], got {}", v));
  return v;
}

double non_negative(SceneConfig& c, const std::string& key, double fallback) {
  const double v = c.get_double(key, fallback);
  require(std::isfinite(v) && v >= 0.0, key, fmt::format("must be >= 0, got {}", v));
  return v;
}

} // namespace

Scene read_scene(SceneConfig& c, const std::string& default_name) {
  Scene s;
  s.name = c.get_string("name", default_name);
  // The run goes to runs/<name>: a name that is a path ('..', '/abs', 'a/b') would leave runs/.
  require(!s.name.empty() && s.name != "." && s.name != ".." &&
              s.name.find_first_of("/\\") == std::string::npos &&
              s.name.find('\0') == std::string::npos,
          "name",
          fmt::format("must be a plain name (no '/', '\\', and not '.' or '..': the run goes to "
                      "runs/<name>), got \"{}\"; use --out DIR to write elsewhere",
                      s.name));

  // Domain.
  s.domain.lo = c.require_vec3("domain.lo");
  s.domain.hi = c.require_vec3("domain.hi");
  s.domain.periodic = c.get_bool3("domain.periodic", {true, true, true});
  for (int a = 0; a < 3; ++a)
    require(std::isfinite(s.domain.lo[a]) && std::isfinite(s.domain.hi[a]) &&
                s.domain.hi[a] > s.domain.lo[a],
            "domain.hi",
            fmt::format("must exceed domain.lo on every axis (axis {}: {} <= {})", a,
                        s.domain.hi[a], s.domain.lo[a]));
  s.gravity = c.get_vec3("gravity", {0, 0, 0});

  // Particles: a CSV file or a generator.
  auto& p = s.particles;
  p.file = c.get_string("particles.file", "");
  // A path in the scene file is relative to the scene's folder; one given on the command line,
  // to the working directory.
  if (!p.file.empty() && !c.overridden("particles.file") && !c.base_dir().empty() &&
      std::filesystem::path(p.file).is_relative())
    p.file = (std::filesystem::path(c.base_dir()) / p.file).string();
  p.seed = static_cast<std::uint64_t>(c.get_int("particles.seed", 1));
  p.allow_overlap = c.get_bool("particles.allow_overlap", false);
  if (p.file.empty()) {
    p.count = c.get_int("particles.count", 0);
    require(p.count >= 0, "particles.count", fmt::format("must be >= 0, got {}", p.count));
    if (c.has("particles.diameter.distribution")) {
      // A table { distribution, mean, std, min, max } (core/diameter_distribution.hpp).
      auto& dd = p.diameters;
      dd.kind = c.get_string("particles.diameter.distribution", "");
      require(dd.kind == "uniform" || dd.kind == "normal" || dd.kind == "lognormal",
              "particles.diameter.distribution",
              fmt::format("must be \"uniform\", \"normal\" or \"lognormal\", got \"{}\"", dd.kind));
      dd.min = positive(c, "particles.diameter.min");
      dd.max = positive(c, "particles.diameter.max");
      require(dd.max > dd.min, "particles.diameter.max",
              fmt::format("must be > particles.diameter.min ({} m), got {} m", dd.min, dd.max));
      if (dd.kind == "uniform") {
        for (const char* k : {"particles.diameter.mean", "particles.diameter.std"})
          require(!c.has(k), k, "a uniform distribution takes only min and max");
        dd.mean = 0.5 * (dd.min + dd.max);
      } else {
        dd.mean = positive(c, "particles.diameter.mean");
        dd.std = positive(c, "particles.diameter.std");
      }
      p.diameter = dd.max;
    } else {
      p.diameter = positive(c, "particles.diameter");
      p.diameters.kind = "fixed", p.diameters.mean = p.diameter;
    }
    p.density = positive(c, "particles.density");
    p.temperature = non_negative(c, "particles.temperature", 0.0);
    p.velocity = c.get_vec3("particles.velocity", {0, 0, 0});
    p.placement = c.get_string("particles.placement", "random");
    require(p.placement == "random" || p.placement == "lattice", "particles.placement",
            fmt::format("must be \"random\" or \"lattice\", got \"{}\"", p.placement));
    p.region_lo = c.get_vec3("particles.region_lo", s.domain.lo);
    p.region_hi = c.get_vec3("particles.region_hi", s.domain.hi);
    for (int a = 0; a < 3; ++a) {
      require(p.region_lo[a] >= s.domain.lo[a] && p.region_hi[a] <= s.domain.hi[a] &&
                  p.region_hi[a] > p.region_lo[a],
              "particles.region_hi",
              fmt::format("the region must be non-empty and inside the domain (axis {})", a));
      require(p.diameter < s.domain.length(a), "particles.diameter",
              fmt::format("{} m does not fit in the domain (axis {} is {} m long)", p.diameter, a,
                          s.domain.length(a)));
    }
  } else {
    for (const char* k : {"particles.count", "particles.diameter", "particles.density",
                          "particles.temperature", "particles.placement"})
      require(!c.has(k), k, "cannot be combined with particles.file");
  }

  // DEM contact model.
  auto& d = s.dem;
  d.scheme = c.get_string("dem.scheme", "explicit");
  require(d.scheme == "explicit" || d.scheme == "orb" || d.scheme == "islands", "dem.scheme",
          fmt::format("unknown scheme \"{}\" (available: \"explicit\", \"orb\", \"islands\")",
                      d.scheme));
  d.spring_constant = positive(c, "dem.spring_constant");
  d.restitution = unit_interval(c, "dem.restitution", 0.0);
  require(c.has("dem.restitution"), "dem.restitution", "is required but missing");
  d.friction = non_negative(c, "dem.friction", 0.0);
  d.tangential_stiffness_ratio = c.get_double("dem.tangential_stiffness_ratio", 2.0 / 7.0);
  require(d.tangential_stiffness_ratio > 0.0, "dem.tangential_stiffness_ratio", "must be > 0");
  d.tangential_damping_ratio = non_negative(c, "dem.tangential_damping_ratio", 0.5);
  d.wall_spring_constant = c.get_double("dem.wall_spring_constant", d.spring_constant);
  require(d.wall_spring_constant > 0.0, "dem.wall_spring_constant", "must be > 0");
  d.wall_restitution = unit_interval(c, "dem.wall_restitution", d.restitution);
  d.wall_friction = non_negative(c, "dem.wall_friction", d.friction);
  d.dt_factor = c.get_double("dem.dt_factor", 0.02);
  require(std::isfinite(d.dt_factor) && d.dt_factor > 0.0, "dem.dt_factor",
          fmt::format("must be > 0, got {}", d.dt_factor));
  d.dt = c.get_double("dem.dt", 0.0);
  require(std::isfinite(d.dt) && d.dt >= 0.0, "dem.dt",
          fmt::format("must be > 0 (or 0 for dt = tau_p * dem.dt_factor), got {}", d.dt));
  d.neighbor_skin = c.get_double("dem.neighbor_skin", -1.0); // resolved once sizes are known
  require(d.neighbor_skin == -1.0 || d.neighbor_skin > 0.0, "dem.neighbor_skin", "must be > 0");
  d.max_overlap = c.get_double("dem.max_overlap", 0.3);
  require(d.max_overlap > 0.0 && d.max_overlap < 1.0, "dem.max_overlap",
          "must be in (0, 1) (a fraction of the smaller radius)");
  d.nsubit = c.get_int("dem.nsubit", 10);
  require(d.nsubit >= 1, "dem.nsubit", fmt::format("must be >= 1, got {}", d.nsubit));
  d.proximity_radii = c.get_double("dem.proximity_radii", 3.0);
  require(std::isfinite(d.proximity_radii) && d.proximity_radii > 0.0, "dem.proximity_radii",
          fmt::format("must be > 0, got {}", d.proximity_radii));
  d.local_dt = c.get_string("dem.local_dt", "proximity");
  require(d.local_dt == "proximity" || d.local_dt == "time_to_contact", "dem.local_dt",
          fmt::format("unknown rule \"{}\" (available: \"proximity\", \"time_to_contact\")",
                      d.local_dt));
  d.regrid_interval = c.get_double("dem.regrid_interval", 1e-4);
  require(std::isfinite(d.regrid_interval) && d.regrid_interval > 0.0, "dem.regrid_interval",
          fmt::format("must be > 0, got {}", d.regrid_interval));
  const std::int64_t levels = c.get_int("partition.orb_levels", 4);
  require(levels >= 0 && levels <= 20, "partition.orb_levels",
          fmt::format("must be in 0..20, got {}", levels));
  s.partition.orb_levels = static_cast<int>(levels);
  s.partition.weights = c.get_string("partition.weights", "count");
  require(
      s.partition.weights == "count" || s.partition.weights == "cost", "partition.weights",
      fmt::format("unknown weights \"{}\" (available: \"count\", \"cost\")", s.partition.weights));
  s.partition.gas_regrid_interval = non_negative(c, "partition.gas_regrid_interval", 0.0);
  s.partition.cell_weight = c.get_double("partition.cell_weight", 400.0);
  require(std::isfinite(s.partition.cell_weight) && s.partition.cell_weight >= 0.0,
          "partition.cell_weight", fmt::format("must be >= 0, got {}", s.partition.cell_weight));

  // Run and output.
  s.run.end_time = positive(c, "run.end_time");
  s.output.interval = c.get_double("output.interval", s.run.end_time / 100.0);
  require(s.output.interval > 0.0, "output.interval", "must be > 0");
  s.output.progress_seconds = c.get_double("output.progress_seconds", 2.0);
  require(s.output.progress_seconds > 0.0, "output.progress_seconds", "must be > 0");
  s.output.snapshot_interval = non_negative(c, "output.snapshot_interval", 0.0);
  s.output.checkpoint_interval = non_negative(c, "output.checkpoint_interval", 0.0);

  // Gas (optional): docs/theory.md §4-§7.
  if (c.has("fluid")) {
    auto& f = s.fluid;
    f.enabled = true;
    const auto cells = c.require_vec3("fluid.cells");
    for (int a = 0; a < 3; ++a) {
      require(cells[a] >= 1 && cells[a] == std::floor(cells[a]), "fluid.cells",
              fmt::format("must be 3 positive whole numbers [nx, ny, nz], got [{}, {}, {}]",
                          cells[0], cells[1], cells[2]));
      require(cells[a] <= 1 << 16, "fluid.cells",
              fmt::format("at most {} cells per axis, got [{}, {}, {}]", 1 << 16, cells[0],
                          cells[1], cells[2]));
      f.cells[a] = static_cast<std::int64_t>(cells[a]);
    }
    // Memory: about 30 doubles per cell (velocities, pressure, solver work arrays).
    const double total = cells[0] * cells[1] * cells[2];
    require(total <= 4.0e9, "fluid.cells",
            fmt::format("{:.3g} cells in all ([{}, {}, {}]) need about {:.3g} TB of memory", total,
                        cells[0], cells[1], cells[2], total * 30 * 8 / 1e12));
    f.cell_size = c.get_vec3("fluid.cell_size", {0, 0, 0});
    for (int a = 0; a < 3; ++a)
      require(f.cell_size[a] >= 0.0, "fluid.cell_size", "must be >= 0 (0: domain / cells)");
    f.density = positive(c, "fluid.density");
    f.viscosity = non_negative(c, "fluid.viscosity", 0.0);
    require(c.has("fluid.viscosity"), "fluid.viscosity", "is required but missing");
    f.dt = non_negative(c, "fluid.dt", 0.0);
    f.cfl = c.get_double("fluid.cfl", 0.4);
    require(std::isfinite(f.cfl) && f.cfl > 0.0, "fluid.cfl",
            fmt::format("must be > 0, got {}", f.cfl));
    f.max_dt = c.get_double("fluid.max_dt", 1e-3);
    require(f.max_dt > 0.0, "fluid.max_dt", "must be > 0");
    f.drag = c.get_string("fluid.drag", "bvk");
    require(f.drag == "bvk" || f.drag == "bvk2" || f.drag == "koch_hill" || f.drag == "wen_yu" ||
                f.drag == "none",
            "fluid.drag",
            fmt::format("unknown drag law \"{}\" (available: \"bvk\", \"bvk2\", "
                        "\"koch_hill\", \"wen_yu\", \"none\")",
                        f.drag));
    f.deposition = c.get_string("fluid.deposition", "trilinear");
    require(f.deposition == "trilinear" || f.deposition == "dpvm" || f.deposition == "dpvm_cube" ||
                f.deposition == "dpvm_sphere",
            "fluid.deposition",
            fmt::format("unknown kernel \"{}\" (available: \"trilinear\", \"dpvm\", "
                        "\"dpvm_sphere\")",
                        f.deposition));
    f.deposition_width = c.get_double("fluid.deposition_width", 2.0);
    require(std::isfinite(f.deposition_width) && f.deposition_width > 0.0, "fluid.deposition_width",
            "must be > 0 (particle diameters)");
    static const char* faces[6] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    for (int k = 0; k < 6; ++k) {
      const std::string key = fmt::format("fluid.bc.{}", faces[k]);
      const bool periodic = s.domain.periodic[static_cast<std::size_t>(k / 2)];
      // Default: the particles' domain (periodic axis periodic, else a no-slip wall).
      f.bc[static_cast<std::size_t>(k)] = c.get_string(key, periodic ? "periodic" : "wall");
      const std::string& b = f.bc[static_cast<std::size_t>(k)];
      require(b == "periodic" || b == "wall" || b == "inflow" || b == "outflow", key,
              fmt::format("unknown boundary \"{}\" (available: \"periodic\", \"wall\", "
                          "\"inflow\", \"outflow\")",
                          b));
      require((b == "periodic") == periodic, key,
              fmt::format("is \"{}\" but domain.periodic is {} on that axis: the gas and the "
                          "particles must agree on periodicity",
                          b, periodic));
    }
    f.inflow_velocity = c.get_vec3("fluid.inflow_velocity", {0, 0, 0});
    f.outflow_pressure = c.get_double("fluid.outflow_pressure", 0.0);
    f.pressure_drop = c.get_vec3("fluid.pressure_drop", {0, 0, 0});
    f.velocity = c.get_vec3("fluid.velocity", {0, 0, 0});
    f.implicit_viscosity = c.get_bool("fluid.implicit_viscosity", false);
    const std::int64_t order = c.get_int("fluid.time_order", 2);
    require(order == 1 || order == 2, "fluid.time_order",
            fmt::format("must be 1 (Euler: one projection per gas step) or 2 (predictor-corrector: "
                        "two), got {}",
                        order));
    f.time_order = static_cast<int>(order);
    f.tolerance = c.get_double("fluid.tolerance", 1e-10);
    require(f.tolerance > 0.0 && f.tolerance < 1.0, "fluid.tolerance", "must be in (0, 1)");
    f.preconditioner = c.get_string("fluid.preconditioner", "pfmg");
    require(f.preconditioner == "pfmg" || f.preconditioner == "smg", "fluid.preconditioner",
            fmt::format("must be \"pfmg\" or \"smg\", got \"{}\"", f.preconditioner));
    f.solver = c.get_string("fluid.solver", "auto");
    require(f.solver == "multigrid" || f.solver == "hypre" || f.solver == "auto", "fluid.solver",
            fmt::format("must be \"multigrid\", \"hypre\" or \"auto\", got \"{}\"", f.solver));
  }

  c.check_all_used();
  return s;
}

} // namespace cfddem

namespace cfddem {

namespace {
std::string vec3(const std::array<double, 3>& v) {
  return fmt::format("[{:.17g}, {:.17g}, {:.17g}]", v[0], v[1], v[2]);
}
std::string bool3(const std::array<bool, 3>& v) {
  return fmt::format("[{}, {}, {}]", v[0], v[1], v[2]);
}
std::string num(double v) {
  return fmt::format("{:.17g}", v);
}
std::string str(const std::string& s) {
  return fmt::format("\"{}\"", s);
}
} // namespace

std::vector<std::pair<std::string, std::string>> describe_scene(const Scene& s) {
  std::vector<std::pair<std::string, std::string>> o;
  o.emplace_back("name", str(s.name));
  o.emplace_back("domain.lo", vec3(s.domain.lo));
  o.emplace_back("domain.hi", vec3(s.domain.hi));
  o.emplace_back("domain.periodic", bool3(s.domain.periodic));
  o.emplace_back("gravity", vec3(s.gravity));
  const auto& p = s.particles;
  if (!p.file.empty()) {
    o.emplace_back("particles.file", str(p.file));
  } else {
    o.emplace_back("particles.count", std::to_string(p.count));
    if (p.diameters.fixed()) {
      o.emplace_back("particles.diameter", num(p.diameter));
    } else {
      o.emplace_back("particles.diameter.distribution", str(p.diameters.kind));
      if (p.diameters.kind != "uniform") {
        o.emplace_back("particles.diameter.mean", num(p.diameters.mean));
        o.emplace_back("particles.diameter.std", num(p.diameters.std));
      }
      o.emplace_back("particles.diameter.min", num(p.diameters.min));
      o.emplace_back("particles.diameter.max", num(p.diameters.max));
    }
    o.emplace_back("particles.density", num(p.density));
    o.emplace_back("particles.temperature", num(p.temperature));
    o.emplace_back("particles.velocity", vec3(p.velocity));
    o.emplace_back("particles.placement", str(p.placement));
    o.emplace_back("particles.region_lo", vec3(p.region_lo));
    o.emplace_back("particles.region_hi", vec3(p.region_hi));
    o.emplace_back("particles.seed", std::to_string(p.seed));
  }
  o.emplace_back("particles.allow_overlap", p.allow_overlap ? "true" : "false");
  const auto& d = s.dem;
  o.emplace_back("dem.scheme", str(d.scheme));
  o.emplace_back("dem.spring_constant", num(d.spring_constant));
  o.emplace_back("dem.restitution", num(d.restitution));
  o.emplace_back("dem.friction", num(d.friction));
  o.emplace_back("dem.tangential_stiffness_ratio", num(d.tangential_stiffness_ratio));
  o.emplace_back("dem.tangential_damping_ratio", num(d.tangential_damping_ratio));
  o.emplace_back("dem.wall_spring_constant", num(d.wall_spring_constant));
  o.emplace_back("dem.wall_restitution", num(d.wall_restitution));
  o.emplace_back("dem.wall_friction", num(d.wall_friction));
  o.emplace_back("dem.dt_factor", num(d.dt_factor));
  o.emplace_back("dem.dt", num(d.dt));
  o.emplace_back("dem.neighbor_skin", d.neighbor_skin > 0 ? num(d.neighbor_skin) : "\"auto\"");
  o.emplace_back("dem.max_overlap", num(d.max_overlap));
  o.emplace_back("dem.nsubit", std::to_string(d.nsubit));
  o.emplace_back("dem.proximity_radii", num(d.proximity_radii));
  o.emplace_back("dem.local_dt", str(d.local_dt));
  o.emplace_back("dem.regrid_interval", num(d.regrid_interval));
  o.emplace_back("partition.orb_levels", std::to_string(s.partition.orb_levels));
  o.emplace_back("partition.weights", str(s.partition.weights));
  o.emplace_back("partition.gas_regrid_interval", num(s.partition.gas_regrid_interval));
  o.emplace_back("partition.cell_weight", num(s.partition.cell_weight));
  o.emplace_back("run.end_time", num(s.run.end_time));
  o.emplace_back("output.interval", num(s.output.interval));
  o.emplace_back("output.progress_seconds", num(s.output.progress_seconds));
  o.emplace_back("output.snapshot_interval", num(s.output.snapshot_interval));
  o.emplace_back("output.checkpoint_interval", num(s.output.checkpoint_interval));
  const auto& f = s.fluid;
  if (f.enabled) {
    o.emplace_back("fluid.cells", fmt::format("[{}, {}, {}]", f.cells[0], f.cells[1], f.cells[2]));
    o.emplace_back("fluid.cell_size", vec3(f.cell_size));
    o.emplace_back("fluid.density", num(f.density));
    o.emplace_back("fluid.viscosity", num(f.viscosity));
    o.emplace_back("fluid.dt", num(f.dt));
    o.emplace_back("fluid.cfl", num(f.cfl));
    o.emplace_back("fluid.max_dt", num(f.max_dt));
    o.emplace_back("fluid.drag", str(f.drag));
    o.emplace_back("fluid.deposition", str(f.deposition));
    o.emplace_back("fluid.deposition_width", num(f.deposition_width));
    static const char* faces[6] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    for (int k = 0; k < 6; ++k)
      o.emplace_back(fmt::format("fluid.bc.{}", faces[k]), str(f.bc[static_cast<std::size_t>(k)]));
    o.emplace_back("fluid.inflow_velocity", vec3(f.inflow_velocity));
    o.emplace_back("fluid.outflow_pressure", num(f.outflow_pressure));
    o.emplace_back("fluid.pressure_drop", vec3(f.pressure_drop));
    o.emplace_back("fluid.velocity", vec3(f.velocity));
    o.emplace_back("fluid.implicit_viscosity", f.implicit_viscosity ? "true" : "false");
    o.emplace_back("fluid.time_order", std::to_string(f.time_order));
    o.emplace_back("fluid.tolerance", num(f.tolerance));
    o.emplace_back("fluid.preconditioner", str(f.preconditioner));
    o.emplace_back("fluid.solver", str(f.solver));
  }
  return o;
}

} // namespace cfddem
