// The `cfddem` program as a user meets it: bad input gives a message naming the key or file and
// exit code 2 with nothing written; a run writes diagnostics.csv and run.json; the thread count
// does not change a single digit of the diagnostics.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <fmt/format.h>
#include <gtest/gtest.h>

namespace fs = std::filesystem;

namespace {

struct Result {
  int code;
  std::string output;
};

Result cfddem(const std::string& args) {
  // One log per test: ctest runs tests of this binary in parallel processes.
  const std::string log = ::testing::TempDir() + "cli_" +
                          ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".txt";
  const std::string cmd = fmt::format("{} {} > {} 2>&1", CFDDEM_BINARY, args, log);
  const int status = std::system(cmd.c_str());
  std::ifstream in(log);
  std::stringstream ss;
  ss << in.rdbuf();
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, ss.str()};
}

std::string read(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

const std::string kScene = std::string(CFDDEM_SOURCE_DIR) + "/scenes/hcs.toml";

// A bad input: exit code 2, the message names what was wrong, the out dir is not created.
void expect_config_error(const std::string& args, const std::string& needle) {
  const fs::path out = fs::path(::testing::TempDir()) /
                       (std::string("never_written_") +
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::remove_all(out);
  const Result r = cfddem(fmt::format("run {} --quiet --out {}", args, out.string()));
  EXPECT_EQ(r.code, 2) << r.output;
  EXPECT_NE(r.output.find(needle), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out)) << "a failed validation must write nothing";
}

} // namespace

TEST(Cli, BadInputsExitWithCode2AndNameTheKey) {
  expect_config_error(kScene + " dem.restitution=1.5", "dem.restitution");
  expect_config_error(kScene + " dem.spring_constant=-1", "dem.spring_constant");
  expect_config_error(kScene + " dem.no_such_key=1", "dem.no_such_key");
  expect_config_error(kScene + " dem.dt_factor=fast", "dem.dt_factor");
  expect_config_error(kScene + " domain.hi=[5e-5,4e-3,4e-3]", "domain.hi");
  expect_config_error(kScene + " particles.file=/no/such.csv", "/no/such.csv");
  expect_config_error("/no/such/scene.toml", "scene file not found");
  expect_config_error("particles.diameter=-1e-4", "particles.diameter");
}

TEST(Cli, OverlappingInitialParticlesNamed) {
  const fs::path csv = fs::path(::testing::TempDir()) / "overlap.csv";
  std::ofstream(csv) << "x,y,z,vx,vy,vz,diameter,density\n1e-3,1e-3,1e-3,0,0,0,1e-4,1000\n"
                        "1.05e-3,1e-3,1e-3,0,0,0,1e-4,1000\n";
  expect_config_error(kScene + " particles.file=" + csv.string(), "particles 0");
}

TEST(Cli, UnstableStepStopsWithCode3) {
  const fs::path out = fs::path(::testing::TempDir()) / "unstable";
  const Result r = cfddem(fmt::format("run {} dem.dt_factor=1.5 --quiet --out {}", kScene,
                                      out.string()));
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("omega dt"), std::string::npos) << r.output;
}

TEST(Cli, CheckPrintsDerivedNumbersAndRunsNothing) {
  const Result r = cfddem("check " + kScene);
  EXPECT_EQ(r.code, 0) << r.output;
  EXPECT_NE(r.output.find("tau_p"), std::string::npos);
  EXPECT_NE(r.output.find("7.236013e-06"), std::string::npos) << r.output; // docs/theory.md §1
  EXPECT_NE(r.output.find("1.447203e-07"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("dem.dt_factor = 0.02"), std::string::npos);
}

TEST(Cli, HelpListsSubcommandsAndKeys) {
  const Result r = cfddem("--help");
  EXPECT_EQ(r.code, 0);
  for (const char* s : {"run", "check", "dem.scheme", "particles.file", "output.interval"})
    EXPECT_NE(r.output.find(s), std::string::npos) << s;
}

namespace {

// A diagnostics.csv without its wall-clock column (wall_seconds, the 16th: index 15).
std::string strip_wall(const std::string& csv) {
  std::stringstream in(csv), out;
  std::string line;
  while (std::getline(in, line)) {
    std::stringstream cells(line);
    std::string cell;
    for (int c = 0; std::getline(cells, cell, ','); ++c)
      if (c != 15) out << cell << ',';
    out << '\n';
  }
  return out.str();
}

} // namespace

// Same scene with 1 and 2 threads: diagnostics identical except the wall-clock column.
TEST(Cli, DiagnosticsIdenticalForOneAndTwoThreads) {
  const fs::path a = fs::path(::testing::TempDir()) / "t1", b = fs::path(::testing::TempDir()) / "t2";
  const std::string common = kScene + " run.end_time=2e-3 output.interval=2e-4 particles.file=" +
                             CFDDEM_SOURCE_DIR + "/scenes/data/hcs1222.csv --quiet";
  ASSERT_EQ(cfddem(fmt::format("run {} --threads 1 --out {}", common, a.string())).code, 0);
  ASSERT_EQ(cfddem(fmt::format("run {} --threads 2 --out {}", common, b.string())).code, 0);
  const std::string da = read(a / "diagnostics.csv"), db = read(b / "diagnostics.csv");
  EXPECT_EQ(std::count(da.begin(), da.end(), '\n'), 12); // header + t = 0 + 10 rows
  EXPECT_EQ(strip_wall(da), strip_wall(db));
  const std::string json = read(a / "run.json");
  for (const char* k : {"\"loop_seconds\"", "\"particle_steps\"", "\"force_evaluations\"",
                        "\"threads\": 1", "\"ranks\": 1", "\"configuration\"", "\"version\""})
    EXPECT_NE(json.find(k), std::string::npos) << k;
}

// An impact faster than a radius per step would tunnel: the run stops with exit code 3 and a
// message naming the particle, the time and the cause.
TEST(Cli, ParticleFasterThanARadiusPerStepStopsWithCode3) {
  const fs::path out = fs::path(::testing::TempDir()) / "too_fast";
  fs::remove_all(out);
  const Result r = cfddem(fmt::format(
      "run {} particles.file= particles.count=20 particles.diameter=1e-4 particles.density=1000 "
      "'particles.velocity=[500, 0, 0]' run.end_time=1e-4 --quiet --out {}",
      kScene, out.string()));
  EXPECT_EQ(r.code, 3) << r.output;
  EXPECT_NE(r.output.find("tunnelling"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("particle "), std::string::npos) << r.output;
}

// No particle, and a single particle: both run to the end and write their outputs.
TEST(Cli, ZeroAndOneParticleRuns) {
  for (int n : {0, 1}) {
    const fs::path out = fs::path(::testing::TempDir()) / fmt::format("n{}", n);
    fs::remove_all(out);
    const Result r = cfddem(fmt::format(
        "run {} particles.file= particles.count={} particles.diameter=1e-4 "
        "particles.density=1000 'particles.velocity=[0.1, 0, 0]' run.end_time=1e-4 "
        "dem.dt=1e-7 output.interval=1e-6 --quiet --out {}",
        kScene, n, out.string()));
    EXPECT_EQ(r.code, 0) << r.output;
    const std::string csv = read(out / "diagnostics.csv");
    EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 1 + 101) << csv;
  }
}

// With a gas (the momentum right-hand side by planes and the interpolation by particle blocks
// run as TBB tasks): a quarter of the fluidized bed (dpvm kernel, walls, inflow and outflow)
// and the riser's periodic pressure drive, 1 and 2 threads, diagnostics identical.
TEST(Cli, CoupledDiagnosticsIdenticalForOneAndTwoThreads) {
  const std::string src = CFDDEM_SOURCE_DIR;
  for (const std::string& scene :
       {src + "/scenes/fluidized_bed.toml particles.count=2500 domain.hi=[0.8e-3,1.0e-2,0.8e-3] "
              "particles.region_hi=[0.8e-3,5.4e-3,0.8e-3] fluid.cells=[16,50,16]",
        src + "/scenes/riser.toml particles.count=2000 fluid.cells=[16,25,16]"}) {
    const fs::path a = fs::path(::testing::TempDir()) / "c1", b = fs::path(::testing::TempDir()) / "c2";
    const std::string common = scene + " run.end_time=4e-4 output.interval=1e-4 --quiet";
    ASSERT_EQ(cfddem(fmt::format("run {} --threads 1 --out {}", common, a.string())).code, 0);
    ASSERT_EQ(cfddem(fmt::format("run {} --threads 2 --out {}", common, b.string())).code, 0);
    const std::string da = read(a / "diagnostics.csv"), db = read(b / "diagnostics.csv");
    EXPECT_EQ(std::count(da.begin(), da.end(), '\n'), 6) << scene; // header + t = 0 + 4 rows
    EXPECT_EQ(strip_wall(da), strip_wall(db)) << scene;
  }
}
