// Fuzz target "checkpoint": model checkpoints (.ckpt), the TensorArchive container of
// core/model/checkpoint (also under .avatar files and training states), read from a file the
// way LoadModelCheckpoint reads it: archive, then its metadata and model config.
#include <nlohmann/json.hpp>
#include <torch/torch.h>

#include "core/model/checkpoint.h"
#include "core/model/model_config.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunCheckpoint(std::string_view input) {
  const std::filesystem::path file = FreshInputDir() / "model.ckpt";
  WriteFile(file, WithArchiveChecksum(input));
  return AcceptAvatarErrors([&] {
    std::string fingerprint;
    const TensorArchive archive = ReadTensorArchive(file, "goha-model", &fingerprint);
    // What the model loader reads next (it throws ModelLoad for json errors; so does this).
    try {
      ModelConfigFromJson(archive.meta.at("config").dump());
      archive.meta.at("step").get<int64_t>();
      archive.meta.at("data_provenance").get<std::string>();
    } catch (const nlohmann::json::exception& e) {
      throw ModelLoad(file.string() + ": checkpoint metadata is incomplete: " + e.what());
    }
    for (const auto& [name, tensor] : archive.tensors) {
      // Touch every element: the tensors must own memory of the size their shape claims.
      if (tensor.numel() > 0) (void)tensor.to(torch::kFloat64).sum().item<double>();
    }
  });
}

int CheckpointSeeds(const std::filesystem::path& dir) {
  int n = 0;
  TensorArchive a;
  a.kind = "goha-model";
  a.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(ModelConfig::Tiny()))},
            {"step", 12},
            {"data_provenance", "fuzz seed"},
            {"created_by", "tests/fuzz"}};
  a.tensors.emplace_back("model.a", torch::arange(12, torch::kFloat32).reshape({3, 4}));
  a.tensors.emplace_back("model.b", torch::ones({2, 2}, torch::kFloat16));
  a.tensors.emplace_back("model.c", torch::arange(5, torch::kInt64));
  a.tensors.emplace_back("model.d", torch::arange(6, torch::kInt32).reshape({1, 2, 3}));
  a.tensors.emplace_back("model.e", torch::full({4}, 7, torch::kUInt8));
  a.tensors.emplace_back("model.f", torch::tensor({true, false, true}));
  a.tensors.emplace_back("model.g", torch::linspace(0, 1, 3, torch::kFloat64));
  a.tensors.emplace_back("model.empty", torch::zeros({0, 3}, torch::kFloat32));
  a.tensors.emplace_back("model.scalar", torch::tensor(3.5f));
  WriteFile(dir / "tiny-model.ckpt", EncodeTensorArchive(a));
  ++n;
  TensorArchive b;
  b.kind = "goha-model";
  b.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(ModelConfig::Cpu()))},
            {"step", 0},
            {"data_provenance", "random init"}};
  WriteFile(dir / "no-tensors.ckpt", EncodeTensorArchive(b));
  ++n;
  return n;
}

AVATAR_FUZZ_TARGET("checkpoint", RunCheckpoint, CheckpointSeeds);

}  // namespace
}  // namespace avatar::fuzz
