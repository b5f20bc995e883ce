// The fuzz targets (tests/fuzz/*_fuzz.cc) in the normal build: every committed input (edge
// seeds under seeds/TARGET/, crash inputs of fixed defects under regressions/TARGET/) must end in
// success or an avatar::Error, and the valid seeds each target makes (scripts/fuzz starts from
// them) must be accepted, so that the fuzzer starts deep inside the parser.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

namespace fs = std::filesystem;

const Target& Find(const std::string& name) {
  for (const auto& t : Targets()) {
    if (t.name == name) return t;
  }
  throw std::runtime_error("fuzz target '" + name + "' is not linked into the replay test");
}

void ReplayCommittedInputs(const std::string& name) {
  const Target& target = Find(name);
  int files = 0;
  for (const char* kind : {"seeds", "regressions"}) {
    const fs::path dir = fs::path(AVATAR_SOURCE_DIR) / "tests" / "fuzz" / kind / target.name;
    if (!fs::is_directory(dir)) continue;
    for (const auto& entry : fs::directory_iterator(dir)) {
      SCOPED_TRACE(entry.path().string());
      EXPECT_NO_THROW(target.run(ReadFile(entry.path())));
      ++files;
    }
  }
  std::printf("%s: %d committed inputs replayed\n", target.name.c_str(), files);
  EXPECT_GT(files, 0) << "commit at least one edge input under tests/fuzz/seeds/" << target.name;
}

void CheckMadeSeeds(const std::string& name) {
  const Target& target = Find(name);
  const fs::path dir = ProcessTempDir() / ("seeds-" + target.name);
  fs::create_directories(dir);
  const int made = target.make_seeds(dir);
  EXPECT_GT(made, 0);
  int accepted = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    SCOPED_TRACE(entry.path().string());
    const bool edge = entry.path().filename().string().rfind("edge-", 0) == 0;
    std::string error;
    ASSERT_NO_THROW(error = target.run(ReadFile(entry.path())));
    if (edge) continue;
    EXPECT_EQ(error, "") << "a valid seed was refused";
    if (error.empty()) ++accepted;
  }
  std::printf("%s: %d seeds made, %d valid ones accepted\n", target.name.c_str(), made, accepted);
  EXPECT_GT(accepted, 0);
}

// One pair of tests per target: FuzzCommittedInputs.X and FuzzMadeSeeds.X.
#define AVATAR_FUZZ_TESTS(TestName, target)                                  \
  TEST(FuzzCommittedInputs, TestName) { ReplayCommittedInputs(target); } \
  TEST(FuzzMadeSeeds, TestName) { CheckMadeSeeds(target); }

AVATAR_FUZZ_TESTS(TfjsGraph, "tfjs_graph")
AVATAR_FUZZ_TESTS(KerasLayers, "keras_layers")
AVATAR_FUZZ_TESTS(Onnx, "onnx")
AVATAR_FUZZ_TESTS(Checkpoint, "checkpoint")
AVATAR_FUZZ_TESTS(AvatarFile, "avatar_file")
AVATAR_FUZZ_TESTS(Dataset, "dataset")
AVATAR_FUZZ_TESTS(Keyframes, "keyframes")
AVATAR_FUZZ_TESTS(ModelConfig, "model_config")
AVATAR_FUZZ_TESTS(Image, "image")
AVATAR_FUZZ_TESTS(Video, "video")
AVATAR_FUZZ_TESTS(Presets, "presets")

// Every target the fuzz build makes is linked here (the list of cmake/AvatarFuzz.cmake).
TEST(FuzzTargets, AllElevenAreRegistered) {
  std::vector<std::string> names;
  for (const auto& t : Targets()) names.push_back(t.name);
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"avatar_file", "checkpoint", "dataset", "image", "keras_layers",
                                             "keyframes", "model_config", "onnx", "presets", "tfjs_graph", "video"}));
}

}  // namespace
}  // namespace avatar::fuzz
