#include "core/scene.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <stdexcept>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "core/error.hpp"
#include "core/scene_keys.hpp"

namespace cfddem {

namespace {

void require(bool ok, const std::string& key, const std::string& why) {
  if (!ok)
    throw ConfigError(fmt::format("scene key '{}'", key), why);
}

// Reads keys through the table (core/scene_keys.cpp): the table's default when a key is absent,
// its range or choices checked when it is present. Reading a key the table lacks, or as another
// type, is a bug of this file (std::logic_error; tests/core/scene_keys_test.cpp reads them all).
class KeyReader {
public:
  explicit KeyReader(SceneConfig& c) : c_(c) {}

  // Keys whose default is a value in the table (or that are required).
  double number(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::Number);
    return checked(k, required(k) ? c_.require_double(key(k))
                                  : c_.get_double(key(k), value<double>(k)));
  }
  std::int64_t integer(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::Integer);
    const std::int64_t v = c_.get_int(key(k), value<std::int64_t>(k));
    (void)checked(k, static_cast<double>(v));
    return v;
  }
  bool flag(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::Bool);
    return c_.get_bool(key(k), value<bool>(k));
  }
  std::string word(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::String);
    return chosen(k, c_.get_string(key(k), std::string(value<std::string_view>(k))));
  }
  std::array<double, 3> vec3(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::Vec3);
    return checked(k, required(k) ? c_.require_vec3(key(k))
                                  : c_.get_vec3(key(k), value<std::array<double, 3>>(k)));
  }
  std::array<bool, 3> bool3(std::string_view name) {
    const SceneKey& k = entry(name, KeyType::Bool3);
    return c_.get_bool3(key(k), value<std::array<bool, 3>>(k));
  }
  // fluid.cells: read as numbers, checked by the caller (whole numbers, the table's range).
  std::array<double, 3> whole3(std::string_view name) {
    return c_.require_vec3(key(entry(name, KeyType::Int3)));
  }

  // Keys whose default the parser computes (the table says SameAs or Derived).
  double number(std::string_view name, double fallback) {
    const SceneKey& k = computed(entry(name, KeyType::Number));
    return checked(k, c_.get_double(key(k), fallback));
  }
  bool flag(std::string_view name, bool fallback) {
    const SceneKey& k = computed(entry(name, KeyType::Bool));
    return c_.get_bool(key(k), fallback);
  }
  std::string word(std::string_view name, const std::string& fallback) {
    const SceneKey& k = computed(entry(name, KeyType::String));
    return chosen(k, c_.get_string(key(k), fallback));
  }
  std::array<double, 3> vec3(std::string_view name, const std::array<double, 3>& fallback) {
    const SceneKey& k = computed(entry(name, KeyType::Vec3));
    return checked(k, c_.get_vec3(key(k), fallback));
  }

private:
  static const SceneKey& entry(std::string_view name, KeyType type) {
    const SceneKey* k = find_scene_key(name);
    if (k == nullptr || k->type != type)
      throw std::logic_error(fmt::format("scene key '{}' is read but {} core/scene_keys.cpp", name,
                                         k ? "has another type in" : "missing from"));
    return *k;
  }
  static const SceneKey& computed(const SceneKey& k) {
    if (k.fallback.kind != KeyDefault::Kind::SameAs && k.fallback.kind != KeyDefault::Kind::Derived)
      throw std::logic_error(fmt::format("scene key '{}': the table holds its default", k.name));
    return k;
  }
  static bool required(const SceneKey& k) { return k.fallback.kind == KeyDefault::Kind::Required; }
  static std::string key(const SceneKey& k) { return std::string(k.name); }
  template <class V> static V value(const SceneKey& k) {
    const V* v = std::get_if<V>(&k.fallback.value);
    if (k.fallback.kind != KeyDefault::Kind::Value || v == nullptr)
      throw std::logic_error(
          fmt::format("scene key '{}': no default of its type in the table", k.name));
    return *v;
  }
  // A value given in the scene outside the key's range is refused; defaults are trusted (the
  // table's own test checks them). No key takes a NaN or an infinity (TOML reads nan and inf):
  // one in a vector used to pass and stop the run at step 0 as "unstable".
  double checked(const SceneKey& k, double v) const {
    if (c_.has(key(k)) && !std::isfinite(v))
      throw ConfigError(c_.where(key(k)), fmt::format("must be a finite number, got {}", v));
    if (k.range.bounded() && c_.has(key(k)) && !k.range.contains(v))
      throw ConfigError(c_.where(key(k)), fmt::format("{}, got {}", must_be(k), v));
    return v;
  }
  std::array<double, 3> checked(const SceneKey& k, const std::array<double, 3>& v) const {
    if (c_.has(key(k)))
      for (std::size_t a = 0; a < 3; ++a)
        if (!std::isfinite(v[a]))
          throw ConfigError(c_.where(key(k)),
                            fmt::format("element {} must be a finite number, got [{}, {}, {}]", a,
                                        v[0], v[1], v[2]));
    if (k.range.bounded() && c_.has(key(k)))
      for (double x : v)
        if (!k.range.contains(x))
          throw ConfigError(c_.where(key(k)), fmt::format("{} on every axis, got [{}, {}, {}]",
                                                          must_be(k), v[0], v[1], v[2]));
    return v;
  }
  // A word given in the scene must be one of the key's choices.
  std::string chosen(const SceneKey& k, std::string v) const {
    if (!k.choices.empty() && c_.has(key(k)) &&
        std::find(k.choices.begin(), k.choices.end(), v) == k.choices.end())
      throw ConfigError(c_.where(key(k)), fmt::format("unknown value \"{}\" (available: \"{}\")", v,
                                                      fmt::join(k.choices, "\", \"")));
    return v;
  }

  SceneConfig& c_;
};

// A size distribution, the table `<key> = { distribution, mean, std, min, max }`
// (core/diameter_distribution.hpp), for the particles or an inlet.
DiameterDistribution read_diameters(KeyReader& k, const SceneConfig& c, const std::string& key) {
  DiameterDistribution dd;
  dd.key = key;
  dd.kind = k.word(key + ".distribution", "");
  dd.min = k.number(key + ".min");
  dd.max = k.number(key + ".max");
  require(dd.max > dd.min, key + ".max",
          fmt::format("must be > {}.min ({} m), got {} m", key, dd.min, dd.max));
  if (dd.kind == "uniform") {
    for (const std::string& g : {key + ".mean", key + ".std"})
      require(!c.has(g), g, "a uniform distribution takes only min and max");
    dd.mean = 0.5 * (dd.min + dd.max);
  } else {
    dd.mean = k.number(key + ".mean");
    dd.std = k.number(key + ".std");
  }
  return dd;
}

// domain.shape and the cylinder's keys (read for a box too, where the cylinder's keys are
// refused when given): a column that fits inside the box, across walled axes only.
void read_cylinder(KeyReader& k, const SceneConfig& c, Scene& s) {
  DomainSpec& d = s.domain;
  d.shape = k.word("domain.shape");
  const std::string axis = k.word("domain.cylinder_axis");
  d.cylinder_axis = axis == "x" ? 0 : axis == "z" ? 2 : 1;
  const auto [u, w] = d.cross_axes();
  const double fit = 0.5 * std::min(d.length(u), d.length(w));
  d.cylinder_radius = k.number("domain.cylinder_radius", fit);
  if (!d.cylinder()) {
    for (const char* g : {"domain.cylinder_axis", "domain.cylinder_radius"})
      require(!c.has(g), g, "applies to domain.shape = \"cylinder\" only (the shape is \"box\")");
    return;
  }
  const char* names = "xyz";
  require(!d.periodic[static_cast<std::size_t>(u)] && !d.periodic[static_cast<std::size_t>(w)],
          "domain.periodic",
          fmt::format("must be false on axes {} and {}, across the cylinder (domain.shape = "
                      "\"cylinder\", domain.cylinder_axis = \"{}\"): the curved wall closes them; "
                      "got [{}, {}, {}]",
                      names[u], names[w], axis, d.periodic[0], d.periodic[1], d.periodic[2]));
  require(d.cylinder_radius <= fit, "domain.cylinder_radius",
          fmt::format("{} m does not fit in the box: the column along {} must lie inside it, so "
                      "R is at most half the smaller width across it, {} m",
                      d.cylinder_radius, axis, fit));
}

} // namespace

double DomainSpec::cylinder_area() const {
  return std::numbers::pi * cylinder_radius * cylinder_radius;
}

double DomainSpec::axis_distance_to_box(const std::array<double, 3>& box_lo,
                                        const std::array<double, 3>& box_hi) const {
  double d2 = 0.0;
  for (const int a : cross_axes()) {
    const double d = std::clamp(centre(a), box_lo[a], box_hi[a]) - centre(a);
    d2 += d * d;
  }
  return std::sqrt(d2);
}

std::string DomainSpec::centres_beyond_cylinder(const std::array<double, 3>& box_lo,
                                                const std::array<double, 3>& box_hi,
                                                double r) const {
  const double d = axis_distance_to_box(box_lo, box_hi);
  if (d <= cylinder_radius - r)
    return {};
  return fmt::format("{:.6g} m from it, and a particle of diameter {:.6g} m needs its centre "
                     "within {:.6g} m (domain.cylinder_radius less its radius)",
                     d, 2.0 * r, cylinder_radius - r);
}

Scene read_scene(SceneConfig& c, const std::string& default_name) {
  // A key the table does not know is refused first, with the nearest key: a misspelt required
  // key would otherwise be reported as missing.
  for (const auto& [key, value] : c.flatten())
    if (find_scene_key(key) == nullptr)
      throw ConfigError(c.where(key), unknown_key_hint(key));

  KeyReader k(c);
  Scene s;
  s.name = k.word("name", default_name);
  // The run goes to runs/<name>: a name that is a path ('..', '/abs', 'a/b') would leave runs/.
  require(!s.name.empty() && s.name != "." && s.name != ".." &&
              s.name.find_first_of("/\\") == std::string::npos &&
              s.name.find('\0') == std::string::npos,
          "name",
          fmt::format("must be a plain name (no '/', '\\', and not '.' or '..': the run goes to "
                      "runs/<name>), got \"{}\"; use --out DIR to write elsewhere",
                      s.name));
  // A newline or other control character would make a directory name no listing shows as it is.
  for (std::size_t i = 0; i < s.name.size(); ++i)
    if (const auto ch = static_cast<unsigned char>(s.name[i]); ch < 0x20 || ch == 0x7f)
      throw ConfigError("scene key 'name'",
                        fmt::format("must be a plain name without control characters (a newline, "
                                    "tab, ...), got character code {} at position {}",
                                    static_cast<int>(ch), i));

  // Domain.
  s.domain.lo = k.vec3("domain.lo");
  s.domain.hi = k.vec3("domain.hi");
  s.domain.periodic = k.bool3("domain.periodic");
  for (int a = 0; a < 3; ++a)
    require(std::isfinite(s.domain.lo[a]) && std::isfinite(s.domain.hi[a]) &&
                s.domain.hi[a] > s.domain.lo[a],
            "domain.hi",
            fmt::format("must exceed domain.lo on every axis (axis {}: {} <= {})", a,
                        s.domain.hi[a], s.domain.lo[a]));
  read_cylinder(k, c, s);
  s.gravity = k.vec3("gravity");

  // Particles: a CSV file or a generator.
  auto& p = s.particles;
  p.file = k.word("particles.file");
  // A path in the scene file is relative to the scene's folder; one given on the command line,
  // to the working directory.
  if (!p.file.empty() && !c.overridden("particles.file") && !c.base_dir().empty() &&
      std::filesystem::path(p.file).is_relative())
    p.file = (std::filesystem::path(c.base_dir()) / p.file).string();
  p.seed = static_cast<std::uint64_t>(k.integer("particles.seed"));
  p.allow_overlap = k.flag("particles.allow_overlap");
  p.outflow = k.word("particles.outflow");
  if (p.file.empty()) {
    p.count = k.integer("particles.count");
    if (c.has("particles.diameter.distribution")) {
      p.diameters = read_diameters(k, c, "particles.diameter");
      p.diameter = p.diameters.max;
    } else {
      p.diameter = k.number("particles.diameter"); // diameters stays "fixed"
    }
    p.density = k.number("particles.density");
    p.temperature = k.number("particles.temperature");
    p.velocity = k.vec3("particles.velocity");
    p.placement = k.word("particles.placement");
    p.region_lo = k.vec3("particles.region_lo", s.domain.lo);
    p.region_hi = k.vec3("particles.region_hi", s.domain.hi);
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
    for (const char* g : {"particles.count", "particles.diameter", "particles.density",
                          "particles.temperature", "particles.velocity", "particles.placement",
                          "particles.region_lo", "particles.region_hi"})
      require(!c.has(g), g, "cannot be combined with particles.file");
  }

  // DEM contact model.
  auto& d = s.dem;
  d.scheme = k.word("dem.scheme");
  d.spring_constant = k.number("dem.spring_constant");
  d.restitution = k.number("dem.restitution");
  d.friction = k.number("dem.friction");
  d.tangential_stiffness_ratio = k.number("dem.tangential_stiffness_ratio");
  d.tangential_damping_ratio = k.number("dem.tangential_damping_ratio");
  d.wall_spring_constant = k.number("dem.wall_spring_constant", d.spring_constant);
  d.wall_restitution = k.number("dem.wall_restitution", d.restitution);
  d.wall_friction = k.number("dem.wall_friction", d.friction);
  d.dt_factor = k.number("dem.dt_factor");
  d.dt = k.number("dem.dt");
  d.neighbor_skin = k.number("dem.neighbor_skin", -1.0); // resolved once sizes are known
  d.max_overlap = k.number("dem.max_overlap");
  if (c.holds_string("dem.nsubit")) {
    // "auto" (islands): the table's integer stays the first interval's count.
    const std::string w = c.get_string("dem.nsubit", "");
    if (w != "auto")
      throw ConfigError(c.where("dem.nsubit"),
                        fmt::format("expected an integer >= 1 or \"auto\", got \"{}\"", w));
    if (d.scheme == "orb")
      throw ConfigError(c.where("dem.nsubit"), "\"auto\" is for the islands scheme; orb takes an "
                                               "integer >= 1");
    d.nsubit_auto = d.scheme == "islands";
    d.nsubit = 10;
  } else {
    d.nsubit = k.integer("dem.nsubit");
    // Not given: islands choose their own (docs/schemes.md), orb takes the table's 10.
    d.nsubit_auto = d.scheme == "islands" && !c.has("dem.nsubit");
  }
  d.proximity_radii = k.number("dem.proximity_radii");
  d.local_dt = k.word("dem.local_dt");
  d.orb_global = k.flag("dem.orb_global");
  d.orb_global_min_per_rank = k.integer("dem.orb_global_min_per_rank");
  d.regrid_interval = k.number("dem.regrid_interval");
  s.partition.orb_levels = static_cast<int>(k.integer("partition.orb_levels"));
  s.partition.weights = k.word("partition.weights");
  s.partition.gas_regrid_interval = k.number("partition.gas_regrid_interval");
  s.partition.cell_weight = k.number("partition.cell_weight");

  // Run and output.
  s.run.end_time = k.number("run.end_time");
  s.output.interval = k.number("output.interval", s.run.end_time / 100.0);
  s.output.progress_seconds = k.number("output.progress_seconds");
  s.output.snapshot_interval = k.number("output.snapshot_interval");
  s.output.checkpoint_interval = k.number("output.checkpoint_interval");
  s.output.profile_axis = k.word("output.profile_axis");
  s.output.profile_bins = k.integer("output.profile_bins");
  s.output.contact_census = k.flag("output.contact_census");

  // Gas (optional): docs/theory.md §4-§7.
  if (c.has("fluid")) {
    auto& f = s.fluid;
    f.enabled = true;
    const auto cells = k.whole3("fluid.cells");
    const KeyRange per_axis = find_scene_key("fluid.cells")->range;
    for (int a = 0; a < 3; ++a) {
      require(cells[a] >= per_axis.lo && cells[a] == std::floor(cells[a]), "fluid.cells",
              fmt::format("must be 3 positive whole numbers [nx, ny, nz], got [{}, {}, {}]",
                          cells[0], cells[1], cells[2]));
      require(cells[a] <= per_axis.hi, "fluid.cells",
              fmt::format("at most {} cells per axis, got [{}, {}, {}]", per_axis.hi, cells[0],
                          cells[1], cells[2]));
      f.cells[a] = static_cast<std::int64_t>(cells[a]);
    }
    // Memory: kGasBytesPerCell (apps/gas_check.hpp also refuses a grid beyond this machine's).
    const double total = cells[0] * cells[1] * cells[2];
    require(total <= 4.0e9, "fluid.cells",
            fmt::format("{:.3g} cells in all ([{}, {}, {}]) need about {:.3g} TB of memory", total,
                        cells[0], cells[1], cells[2], total * kGasBytesPerCell / 1e12));
    f.cell_size = k.vec3("fluid.cell_size");
    f.density = k.number("fluid.density");
    f.viscosity = k.number("fluid.viscosity");
    f.dt = k.number("fluid.dt");
    // The run takes whole fluid steps: one longer than the run ran silently to t = fluid.dt.
    require(!(f.dt > s.run.end_time), "fluid.dt",
            fmt::format("{} s is longer than run.end_time = {} s: the run would take one fluid "
                        "step and end at t = {} s; shorten fluid.dt or lengthen run.end_time",
                        f.dt, s.run.end_time, f.dt));
    f.advection = k.word("fluid.advection");
    f.cfl = k.number("fluid.cfl", f.advection == "godunov" ? 0.9 : 0.4);
    f.max_dt = k.number("fluid.max_dt");
    f.drag = k.word("fluid.drag");
    // BVK and Koch-Hill write the drag as 18 mu / d^2 times a function of Re = rho |u| d / mu:
    // 0 x infinity for an inviscid gas (its NaN stopped the projection at the first step). Wen &
    // Yu's tends to Newton's drag as mu -> 0 and runs.
    require(f.viscosity > 0.0 || f.drag == "wen_yu" || f.drag == "none", "fluid.viscosity",
            fmt::format("0 (an inviscid gas) cannot take fluid.drag = \"{}\": the law is 18 mu / "
                        "d^2 times a function of Re = rho |u| d / mu, 0 x infinity at mu = 0; give "
                        "mu > 0, or fluid.drag = \"wen_yu\" (Newton's drag as mu -> 0) or "
                        "\"none\"",
                        f.drag));
    f.one_way = k.word("fluid.coupling") == "one_way";
    f.deposition = k.word("fluid.deposition");
    f.deposition_width = k.number("fluid.deposition_width");
    static const char* faces[6] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    for (int a = 0; a < 6; ++a) {
      const std::string key = fmt::format("fluid.bc.{}", faces[a]);
      const bool periodic = s.domain.periodic[static_cast<std::size_t>(a / 2)];
      // Default: the particles' domain (periodic axis periodic, else a no-slip wall).
      f.bc[static_cast<std::size_t>(a)] = k.word(key, periodic ? "periodic" : "wall");
      const std::string& b = f.bc[static_cast<std::size_t>(a)];
      require((b == "periodic") == periodic, key,
              fmt::format("is \"{}\" but domain.periodic is {} on that axis: the gas and the "
                          "particles must agree on periodicity",
                          b, periodic));
    }
    f.inflow_velocity = k.vec3("fluid.inflow_velocity");
    f.outflow_pressure = k.number("fluid.outflow_pressure");
    f.pressure_drop = k.vec3("fluid.pressure_drop");
    f.velocity = k.vec3("fluid.velocity");
    if (c.holds_string("fluid.implicit_viscosity")) {
      const std::string w = c.get_string("fluid.implicit_viscosity", "");
      if (w != "auto")
        throw ConfigError(c.where("fluid.implicit_viscosity"),
                          fmt::format("expected true, false or \"auto\", got \"{}\"", w));
      f.implicit_viscosity = false;
      f.implicit_viscosity_auto = true;
    } else {
      // Not given: "auto" (implicit_viscosity_auto, the member's default).
      f.implicit_viscosity = k.flag("fluid.implicit_viscosity", false);
      f.implicit_viscosity_auto = !c.has("fluid.implicit_viscosity");
    }
    f.viscous_step = k.word("fluid.viscous_step");
    f.time_order = static_cast<int>(k.integer("fluid.time_order"));
    f.projections = static_cast<int>(k.integer("fluid.projections"));
    for (const char* key : {"fluid.time_order", "fluid.projections"})
      require(!c.has(key) || f.advection == "mol", key,
              "applies to fluid.advection = \"mol\" only: the Godunov step (the default) is one "
              "stage with one projection; set fluid.advection = \"mol\" to choose Euler or Heun");
    f.tolerance = k.number("fluid.tolerance");
    f.preconditioner = k.word("fluid.preconditioner");
    f.solver = k.word("fluid.solver");
    // One cell has no coarser level: the multigrid's coarsest operator is the pinned 1 x 1
    // system, which it cannot factor ("not positive definite" at the first step). hypre solves it.
    require(f.cells[0] * f.cells[1] * f.cells[2] > 1 || f.solver == "hypre", "fluid.cells",
            fmt::format("[1, 1, 1] (a single gas cell) cannot be solved by fluid.solver = \"{}\" "
                        "(our multigrid needs at least 2 cells); give more cells, or fluid.solver "
                        "= \"hypre\"",
                        f.solver));
  }

  // The inlet (apps/particle_inlet.hpp): particles enter at fluid-step boundaries.
  auto& in = s.inlet;
  in.mass_rate = k.number("inlet.mass_rate");
  in.recycle = k.flag("inlet.recycle");
  in.velocity = k.vec3("inlet.velocity");
  in.seed = static_cast<std::uint64_t>(k.integer("inlet.seed"));
  if (c.has("inlet.diameter.distribution")) {
    in.diameters = read_diameters(k, c, "inlet.diameter");
    in.diameter = in.diameters.max;
  } else {
    in.diameter = k.number("inlet.diameter", 0.0);
  }
  in.density = k.number("inlet.density", s.particles.density);
  if (in.enabled()) {
    const char* why = in.recycle ? "inlet.recycle" : "inlet.mass_rate";
    require(s.fluid.enabled, why,
            "particles enter at fluid-step boundaries: the scene needs a [fluid] table");
    require(!in.recycle || s.particles.outflow == "remove", "inlet.recycle",
            "feeds back the particles that leave: particles.outflow must be \"remove\"");
    require(in.mass_rate == 0.0 || s.particles.file.empty(), "inlet.mass_rate",
            "draws the new particles from particles.diameter and particles.density, which a "
            "scene with particles.file does not give; use inlet.recycle");
    for (const char* g : {"inlet.diameter", "inlet.diameter.distribution", "inlet.density"})
      require(!c.has(g) || in.mass_rate > 0.0, g,
              "applies to inlet.mass_rate's new particles only (recycled ones keep their own)");
    const double room = s.domain.cylinder()
                            ? 2.0 * s.domain.cylinder_radius
                            : std::min({s.domain.length(0), s.domain.length(1), s.domain.length(2)});
    require(in.diameter < room, "inlet.diameter",
            fmt::format("{} m does not fit in the domain (at most {} m across)", in.diameter, room));
    for (const char* g : {"inlet.region_lo", "inlet.region_hi"})
      require(c.has(g), g, "is required with an inlet");
    in.region_lo = k.vec3("inlet.region_lo", s.domain.lo);
    in.region_hi = k.vec3("inlet.region_hi", s.domain.hi);
    for (int a = 0; a < 3; ++a)
      require(in.region_lo[a] >= s.domain.lo[a] && in.region_hi[a] <= s.domain.hi[a] &&
                  in.region_hi[a] > in.region_lo[a],
              "inlet.region_hi",
              fmt::format("the region must be non-empty and inside the domain (axis {})", a));
  } else { // an inlet switched off (mass_rate 0, no recycle): its region is read, unused
    for (const char* g : {"inlet.diameter", "inlet.diameter.distribution", "inlet.density"})
      require(!c.has(g), g, "applies to inlet.mass_rate's new particles only (it is 0)");
    in.region_lo = k.vec3("inlet.region_lo", s.domain.lo);
    in.region_hi = k.vec3("inlet.region_hi", s.domain.hi);
  }

  c.check_all_used();
  return s;
}

} // namespace cfddem

namespace cfddem {

namespace {
// As the key table writes values (17 significant digits).
std::string vec3(const std::array<double, 3>& v) {
  return toml_text(v);
}
std::string bool3(const std::array<bool, 3>& v) {
  return toml_text(v);
}
std::string num(double v) {
  return toml_text(v);
}
std::string str(const std::string& s) {
  return toml_text(std::string_view(s));
}
// A size distribution's lines under its own key (DiameterDistribution::key), as read_diameters
// reads them.
void describe_diameters(std::vector<std::pair<std::string, std::string>>& o,
                        const DiameterDistribution& dd) {
  o.emplace_back(dd.key + ".distribution", str(dd.kind));
  if (dd.kind != "uniform") {
    o.emplace_back(dd.key + ".mean", num(dd.mean));
    o.emplace_back(dd.key + ".std", num(dd.std));
  }
  o.emplace_back(dd.key + ".min", num(dd.min));
  o.emplace_back(dd.key + ".max", num(dd.max));
}
} // namespace

std::vector<std::pair<std::string, std::string>> describe_scene(const Scene& s) {
  std::vector<std::pair<std::string, std::string>> o;
  o.emplace_back("name", str(s.name));
  o.emplace_back("domain.lo", vec3(s.domain.lo));
  o.emplace_back("domain.hi", vec3(s.domain.hi));
  o.emplace_back("domain.periodic", bool3(s.domain.periodic));
  // A box lists none of the shape's keys: its configuration (run.json, checkpoints) reads as
  // before they existed, so older checkpoints restart and box runs stay byte for byte.
  if (s.domain.cylinder()) {
    o.emplace_back("domain.shape", str(s.domain.shape));
    o.emplace_back("domain.cylinder_axis",
                   str(std::string(1, "xyz"[static_cast<std::size_t>(s.domain.cylinder_axis)])));
    o.emplace_back("domain.cylinder_radius", num(s.domain.cylinder_radius));
  }
  o.emplace_back("gravity", vec3(s.gravity));
  const auto& p = s.particles;
  if (!p.file.empty()) {
    o.emplace_back("particles.file", str(p.file));
  } else {
    o.emplace_back("particles.count", std::to_string(p.count));
    if (p.diameters.fixed()) {
      o.emplace_back("particles.diameter", num(p.diameter));
    } else {
      describe_diameters(o, p.diameters);
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
  o.emplace_back("particles.outflow", str(p.outflow));
  if (s.inlet.enabled()) { // absent otherwise: checkpoints of scenes without one still match
    o.emplace_back("inlet.mass_rate", num(s.inlet.mass_rate));
    o.emplace_back("inlet.recycle", s.inlet.recycle ? "true" : "false");
    o.emplace_back("inlet.region_lo", vec3(s.inlet.region_lo));
    o.emplace_back("inlet.region_hi", vec3(s.inlet.region_hi));
    o.emplace_back("inlet.velocity", vec3(s.inlet.velocity));
    if (s.inlet.mass_rate > 0.0) { // a recycling inlet's configuration lines stay as before
      // The inlet's size or distribution, or the particles' fixed size (a distribution of the
      // particles' is theirs, listed above).
      if (!s.inlet.diameters.fixed()) {
        describe_diameters(o, s.inlet.diameters);
      } else {
        const double d = s.inlet.diameter > 0.0         ? s.inlet.diameter
                         : s.particles.diameters.fixed() ? s.particles.diameter
                                                         : 0.0;
        if (d > 0.0)
          o.emplace_back("inlet.diameter", num(d));
      }
      o.emplace_back("inlet.density", num(s.inlet.density));
    }
    o.emplace_back("inlet.seed", std::to_string(s.inlet.seed));
  }
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
  o.emplace_back("dem.nsubit", d.nsubit_auto ? std::string("\"auto\"") : std::to_string(d.nsubit));
  o.emplace_back("dem.proximity_radii", num(d.proximity_radii));
  o.emplace_back("dem.local_dt", str(d.local_dt));
  o.emplace_back("dem.orb_global", d.orb_global ? "true" : "false");
  o.emplace_back("dem.orb_global_min_per_rank", std::to_string(d.orb_global_min_per_rank));
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
  o.emplace_back("output.profile_axis", str(s.output.profile_axis));
  o.emplace_back("output.profile_bins", std::to_string(s.output.profile_bins));
  o.emplace_back("output.contact_census", s.output.contact_census ? "true" : "false");
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
    o.emplace_back("fluid.coupling", str(f.one_way ? "one_way" : "two_way"));
    o.emplace_back("fluid.deposition", str(f.deposition));
    o.emplace_back("fluid.deposition_width", num(f.deposition_width));
    static const char* faces[6] = {"x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi"};
    for (int k = 0; k < 6; ++k)
      o.emplace_back(fmt::format("fluid.bc.{}", faces[k]), str(f.bc[static_cast<std::size_t>(k)]));
    o.emplace_back("fluid.inflow_velocity", vec3(f.inflow_velocity));
    o.emplace_back("fluid.outflow_pressure", num(f.outflow_pressure));
    o.emplace_back("fluid.pressure_drop", vec3(f.pressure_drop));
    o.emplace_back("fluid.velocity", vec3(f.velocity));
    o.emplace_back("fluid.implicit_viscosity", f.implicit_viscosity_auto ? "\"auto\""
                                               : f.implicit_viscosity    ? "true"
                                                                         : "false");
    o.emplace_back("fluid.viscous_step", str(f.viscous_step));
    o.emplace_back("fluid.advection", str(f.advection));
    o.emplace_back("fluid.time_order", std::to_string(f.time_order));
    o.emplace_back("fluid.projections", std::to_string(f.projections));
    o.emplace_back("fluid.tolerance", num(f.tolerance));
    o.emplace_back("fluid.preconditioner", str(f.preconditioner));
    o.emplace_back("fluid.solver", str(f.solver));
  }
  return o;
}

} // namespace cfddem
