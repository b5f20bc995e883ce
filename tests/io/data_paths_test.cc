#include "core/io/data_paths.h"

#include <gtest/gtest.h>

#include <cstdlib>

#include "common/temp_dir.h"
#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

class EnvGuard {
 public:
  explicit EnvGuard(const char* name) : name_(name) {
    const char* v = std::getenv(name);
    had_ = v != nullptr;
    if (had_) value_ = v;
  }
  ~EnvGuard() {
    if (had_) {
      setenv(name_, value_.c_str(), 1);
    } else {
      unsetenv(name_);
    }
  }

 private:
  const char* name_;
  bool had_ = false;
  std::string value_;
};

TEST(DataPaths, OptionThenEnvironmentThenCache) {
  EnvGuard data("AVATAR_DATA_DIR"), xdg("XDG_CACHE_HOME");
  setenv("AVATAR_DATA_DIR", "/from/env", 1);
  setenv("XDG_CACHE_HOME", "/xdg", 1);
  EXPECT_EQ(DataPaths::Resolve("/from/option").Root(), "/from/option");
  EXPECT_EQ(DataPaths::Resolve("/from/option").Source(), "option");
  EXPECT_EQ(DataPaths::Resolve().Root(), "/from/env");
  unsetenv("AVATAR_DATA_DIR");
  EXPECT_EQ(DataPaths::Resolve().Root(), "/xdg/avatar-studio");
  EXPECT_EQ(DataPaths::Resolve().Source(), "default cache");
}

TEST(DataPaths, RequireSaysWhatIsMissingAndHowToGetIt) {
  TempDir dir;
  const DataPaths paths = DataPaths::Resolve(dir.path().string());
  try {
    paths.Require("models/facemesh.json", "the 468-point face mesh");
    FAIL();
  } catch (const MissingData& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("models/facemesh.json"), std::string::npos) << what;
    EXPECT_NE(what.find("468-point face mesh"), std::string::npos) << what;
    EXPECT_NE(what.find("scripts/setup"), std::string::npos) << what;
    EXPECT_NE(what.find("--data-dir"), std::string::npos) << what;
  }
  std::filesystem::create_directories(dir / "models");
  WriteBytesAtomically(dir / "models" / "facemesh.json", "{}");
  EXPECT_EQ(paths.Require("models/facemesh.json", "x"), dir / "models" / "facemesh.json");
}

}  // namespace
}  // namespace avatar
