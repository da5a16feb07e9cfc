// core/mpi_start.hpp: a singleton tells Open MPI it runs alone; a launched rank and a user's own
// settings are left as they are.
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/mpi_start.hpp"

namespace cfddem {
namespace {

// Clears the variables the function reads and writes, and puts back what was there after the
// test (ctest may itself run under a launcher's environment).
class MpiStartEnv : public ::testing::Test {
protected:
  const std::vector<std::string> keys_ = {"OMPI_COMM_WORLD_SIZE",
                                          "PMIX_RANK",
                                          "PMI_RANK",
                                          "PMI_SIZE",
                                          "SLURM_PROCID",
                                          "OMPI_MCA_ess_singleton_isolated",
                                          "OMPI_MCA_pml"};
  std::vector<std::optional<std::string>> saved_;

  void SetUp() override {
    for (const std::string& key : keys_) {
      const char* value = std::getenv(key.c_str());
      saved_.push_back(value != nullptr ? std::optional<std::string>(value) : std::nullopt);
      unsetenv(key.c_str());
    }
  }
  void TearDown() override {
    for (std::size_t i = 0; i < keys_.size(); ++i) {
      if (saved_[i]) {
        setenv(keys_[i].c_str(), saved_[i]->c_str(), 1);
      } else {
        unsetenv(keys_[i].c_str());
      }
    }
  }
  static std::string value(const char* key) {
    const char* v = std::getenv(key);
    return v != nullptr ? v : "<unset>";
  }
};

TEST_F(MpiStartEnv, ASingletonRunsIsolatedOnTheSelfTransport) {
  EXPECT_FALSE(started_by_mpi_launcher());
  prepare_mpi_init();
  EXPECT_EQ(value("OMPI_MCA_ess_singleton_isolated"), "1");
  EXPECT_EQ(value("OMPI_MCA_pml"), "ob1");
}

TEST_F(MpiStartEnv, TheUsersOwnSettingIsKept) {
  setenv("OMPI_MCA_pml", "ucx", 1);
  prepare_mpi_init();
  EXPECT_EQ(value("OMPI_MCA_pml"), "ucx");
  EXPECT_EQ(value("OMPI_MCA_ess_singleton_isolated"), "1");
}

TEST_F(MpiStartEnv, ALaunchedRankIsLeftAsItsLauncherSetItUp) {
  for (const char* key :
       {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE", "SLURM_PROCID"}) {
    SCOPED_TRACE(key);
    setenv(key, "0", 1);
    EXPECT_TRUE(started_by_mpi_launcher());
    prepare_mpi_init();
    EXPECT_EQ(value("OMPI_MCA_ess_singleton_isolated"), "<unset>");
    EXPECT_EQ(value("OMPI_MCA_pml"), "<unset>");
    unsetenv(key);
  }
}

} // namespace
} // namespace cfddem
