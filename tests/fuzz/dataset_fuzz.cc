// Fuzz target "dataset": training datasets (core/train/dataset): dataset.json and the pickled
// tensor shards, opened and read the way `train` and `dataset inspect` do (every split, a
// sample, one batch). Input: a MultiFile (fuzz_common.h), dataset.json first, then the shards
// under their names (shards/train.pt ...).
#include <nlohmann/json.hpp>
#include <torch/serialize.h>
#include <torch/torch.h>

#include "core/train/dataset.h"
#include "core/util/error.h"
#include "fuzz_common.h"
#include "tests/common/dataset_shard.h"

namespace avatar::fuzz {
namespace {

std::string ReadSplit(const std::filesystem::path& dir, const std::string& split) {
  return AcceptAvatarErrors([&] {
    const train::TrainDataset ds = train::TrainDataset::Open(dir.string(), split);
    (void)ds.frames();
    (void)ds.CountKind(train::PairKind{});
    (void)ds.Identities();
    if (ds.size() > 0) {
      (void)ds.Get(0);
      (void)ds.Get(ds.size() - 1);
      train::LoaderOptions options;
      options.batch_size = 2;
      train::DataLoader loader(ds, options);
      train::TrainBatch batch;
      (void)loader.Next(&batch);
    }
  });
}

// Accepted when every split it lists opens and reads.
std::string RunDataset(std::string_view input) {
  const std::filesystem::path dir = FreshInputDir();
  WriteParts(dir, SplitParts(input, "dataset.json"));
  std::string error = ReadSplit(dir, "train");
  const std::string val = ReadSplit(dir, "val");
  if (error.empty()) error = val;
  if (train::TrainDataset::HasSynthetic(dir.string())) {
    const std::string synthetic = ReadSplit(dir, "synthetic");
    if (error.empty()) error = synthetic;
  }
  return error;
}

// A shard as dataset_build writes it: n frames of s x s pixels, k expression coefficients,
// `pairs` pairs.
std::string Shard(int64_t n, int64_t s, int64_t k, int64_t pairs, int64_t seed) {
  torch::manual_seed(seed);
  return testing::DatasetShardBytes(n, s, k, torch::arange(n, torch::kInt64).remainder(2), [&] {
    return std::make_pair(torch::randint(0, n, {pairs, 2}, torch::kInt64), torch::randint(0, 2, {pairs}, torch::kInt64));
  });
}

int DatasetSeeds(const std::filesystem::path& dir) {
  using nlohmann::json;
  int n = 0;
  for (const bool synthetic : {false, true}) {
    json shards = {{"train", "shards/train.pt"}, {"val", "shards/val.pt"}};
    if (synthetic) shards["synthetic"] = "shards/synthetic.pt";
    json labels = json::array();
    for (int i = 0; i < 3; ++i) labels.push_back({"frame" + std::to_string(i) + ".png", std::vector<float>(25, 0.5f)});
    const json ds = {{"size", 8}, {"split", {{"train", 3}, {"val", 2}}}, {"shards", shards}, {"labels", labels},
                     {"counts", {{"photos", 3}}}};
    std::vector<std::pair<std::string, std::string>> parts = {{"dataset.json", ds.dump(1)},
                                                              {"shards/train.pt", Shard(3, 8, 4, 3, 1)},
                                                              {"shards/val.pt", Shard(2, 8, 4, 1, 2)}};
    if (synthetic) parts.emplace_back("shards/synthetic.pt", Shard(2, 8, 4, 2, 3));
    WriteFile(dir / (synthetic ? "tiny-synthetic" : "tiny"), JoinParts(parts));
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("dataset", RunDataset, DatasetSeeds);

}  // namespace
}  // namespace avatar::fuzz
