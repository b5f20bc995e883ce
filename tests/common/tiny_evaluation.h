#pragma once
// The inputs of the tests that evaluate a network on a dataset (eval, bench accuracy): one folder
// per test suite with the tiny dataset of tiny_dataset.h (two validation identities) and tiny
// random-weight checkpoints, and `avatar-studio` run as those tests run it.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "common/tiny_checkpoint.h"
#include "common/tiny_dataset.h"
#include "core/tools/dataset_build.h"
#include "core/util/run_context.h"

namespace avatar::testing {

struct TinyEvaluationInputs {
  TempDir dir;
  DatasetBuildReport report;  // of the dataset in Data()

  std::filesystem::path Data() const { return dir / "ds"; }
  // A checkpoint saved by MakeTinyEvaluationInputs, by file name.
  std::filesystem::path Checkpoint(const std::string& name) const { return dir / name; }
};

// Builds the dataset (TinyDatasetOptions(Data(), 2) from TinyDatasetPhotos()) and saves one
// ModelConfig::Tiny() network with random weights (torch seed `seed`, SaveTinyCheckpoint) once
// per (file name, checkpoint info) of `checkpoints`. Throws as BuildDataset and SaveModelCheckpoint.
inline std::unique_ptr<TinyEvaluationInputs> MakeTinyEvaluationInputs(
    uint64_t seed, const std::vector<std::pair<std::string, CheckpointInfo>>& checkpoints) {
  auto inputs = std::make_unique<TinyEvaluationInputs>();
  RunContext ctx;
  inputs->report = BuildDataset(TinyDatasetOptions(inputs->Data(), 2), TinyDatasetPhotos(), {}, ctx);
  for (const auto& [name, info] : checkpoints) SaveTinyCheckpoint(inputs->Checkpoint(name), seed, info);
  return inputs;
}

// `avatar-studio ARGS` (`exe` is the binary, ARGS already quoted) without a display, two threads.
inline ProcessResult RunStudio(const std::string& exe, const std::string& args) {
  return RunProcess("'" + exe + "' " + args, "env -u DISPLAY AVATAR_THREADS=2");
}

}  // namespace avatar::testing
