#include "core/util/threads.h"

#include <ATen/Parallel.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <thread>

#include <cstdlib>

#include "core/util/error.h"

namespace avatar {
namespace {

class ThreadsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const char* env = std::getenv("AVATAR_THREADS");
    had_env_ = env != nullptr;
    if (had_env_) saved_env_ = env;
  }
  void TearDown() override {
    if (had_env_) {
      setenv("AVATAR_THREADS", saved_env_.c_str(), 1);
    } else {
      unsetenv("AVATAR_THREADS");
    }
  }
  bool had_env_ = false;
  std::string saved_env_;
};

TEST_F(ThreadsTest, ExplicitRequestWins) {
  setenv("AVATAR_THREADS", "2", 1);
  EXPECT_EQ(ConfigureThreads(1), 1);
  EXPECT_EQ(at::get_num_threads(), 1);
  EXPECT_EQ(ConfiguredThreads(), 1);
}

TEST_F(ThreadsTest, EnvironmentOverridesTheDefault) {
  setenv("AVATAR_THREADS", "2", 1);
  EXPECT_EQ(ConfigureThreads(0), 2);
  EXPECT_EQ(at::get_num_threads(), 2);
}

TEST_F(ThreadsTest, DefaultIsAllCores) {
  unsetenv("AVATAR_THREADS");
  const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  EXPECT_EQ(ConfigureThreads(0), cores);
  EXPECT_EQ(at::get_num_threads(), cores);
  EXPECT_EQ(ConfiguredThreads(), cores);
}

TEST_F(ThreadsTest, MalformedValuesAreRejected) {
  setenv("AVATAR_THREADS", "two", 1);
  EXPECT_THROW(ConfigureThreads(0), InvalidOptions);
  EXPECT_THROW(ConfigureThreads(-1), InvalidOptions);
}

}  // namespace
}  // namespace avatar
