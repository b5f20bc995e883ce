// Fuzz target "model_config": model config JSON (`train --config FILE`, and the config stored in
// every checkpoint and .avatar file), core/model/model_config ModelConfigFromJson.
#include "core/model/model_config.h"
#include "core/util/error.h"
#include "fuzz_common.h"

namespace avatar::fuzz {
namespace {

std::string RunModelConfig(std::string_view input) {
  return AcceptAvatarErrors([&] {
    const ModelConfig config = ModelConfigFromJson(std::string(input));
    // A config that loads must survive a round trip unchanged.
    if (ModelConfigFromJson(ModelConfigToJson(config)) != config) {
      throw std::logic_error("model config changes in a JSON round trip");
    }
  });
}

int ModelConfigSeeds(const std::filesystem::path& dir) {
  int n = 0;
  for (const char* name : {"paper", "lite", "cpu", "tiny"}) {
    WriteFile(dir / (std::string(name) + ".json"), ModelConfigToJson(ModelConfig::FromName(name)));
    ++n;
  }
  return n;
}

AVATAR_FUZZ_TARGET("model_config", RunModelConfig, ModelConfigSeeds);

}  // namespace
}  // namespace avatar::fuzz
