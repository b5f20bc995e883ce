#pragma once
// Tiny random-weight model checkpoints for tests that load a network from a file.

#include <cstdint>
#include <filesystem>

#include <torch/torch.h>

#include "core/model/goha_model.h"

namespace avatar::testing {

// Saves a ModelConfig::Tiny() network with random weights (torch seed `seed`) at `path` with
// `info` and returns it. `expression_bases`: the "bases" expression model (ModelConfig
// expression_model), its bases drawn from N(0,1) (a fresh network's are zeros: T_e would be 0).
inline GohaModel SaveTinyCheckpoint(const std::filesystem::path& path, uint64_t seed, const CheckpointInfo& info = {},
                                    bool expression_bases = false) {
  ModelConfig config = ModelConfig::Tiny();
  if (expression_bases) config.expression_model = "bases";
  torch::manual_seed(seed);
  GohaModel model(config);
  if (expression_bases) {
    torch::NoGradGuard no_grad;
    model->expression_bases.normal_(0.0, 1.0);
  }
  SaveModelCheckpoint(path, model, info);
  return model;
}

}  // namespace avatar::testing
