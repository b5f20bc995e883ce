#include "core/pipeline/avatar_file.h"

#include <sstream>

#include <nlohmann/json.hpp>

#include "core/model/checkpoint.h"
#include "core/pipeline/avatar_file_info.h"
#include "core/util/error.h"

namespace avatar {
void WriteAvatarFile(const AvatarState& s, const std::filesystem::path& path) {
  TensorArchive archive;
  archive.kind = "goha-avatar";
  archive.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(s.config))},
                  {"model_id", s.model_id},
                  {"camera", std::vector<float>(s.camera.begin(), s.camera.end())},
                  {"expression_kind", s.expressions ? s.expressions->Kind() : std::string()}};
  if (!s.refinement.empty()) archive.meta["refinement"] = nlohmann::json::parse(s.refinement);
  archive.tensors.emplace_back("avatar.canonical", s.canonical);
  archive.tensors.emplace_back("avatar.appearance", s.appearance);
  cv::Mat src = s.source.isContinuous() ? s.source : s.source.clone();
  archive.tensors.emplace_back("avatar.source_image",
                               torch::from_blob(src.data, {src.rows, src.cols, 3}, torch::kUInt8).clone());
  const std::string bytes = s.expressions ? s.expressions->Serialize() : std::string();
  archive.tensors.emplace_back(
      "avatar.expression_source",
      torch::from_blob(const_cast<char*>(bytes.data()), {static_cast<int64_t>(bytes.size())}, torch::kUInt8).clone());
  WriteTensorArchive(path, archive);
}

std::shared_ptr<AvatarState> ReadAvatarFile(const std::filesystem::path& path, const ModelConfig& c,
                                            const std::string& model_id) {
  const TensorArchive archive = ReadTensorArchive(path, "goha-avatar");
  const std::string file = path.string();
  auto state = std::make_shared<AvatarState>();
  std::string kind;
  try {
    state->config = ModelConfigFromJson(archive.meta.at("config").dump());
    state->model_id = archive.meta.at("model_id").get<std::string>();
    const auto camera = archive.meta.at("camera").get<std::vector<float>>();
    if (camera.size() != 25) throw ModelLoad(file + ": camera label must have 25 values");
    std::copy(camera.begin(), camera.end(), state->camera.begin());
    kind = archive.meta.at("expression_kind").get<std::string>();
    if (archive.meta.contains("refinement")) state->refinement = archive.meta.at("refinement").dump();
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(file + ": avatar metadata is incomplete: " + e.what());
  } catch (const InvalidOptions& e) {
    throw ModelLoad(file + ": avatar holds an invalid model config: " + e.what());
  }
  if (state->config != c) {
    // Configs of one name can differ (an ablation's `expression_model`, `appearance_branch`), so
    // the models are named by their ids as well.
    throw ModelLoad(file + ": the avatar was made with model '" + state->model_id + "' (config '" +
                    state->config.name + "') but this session runs model '" + model_id + "' (config '" + c.name +
                    (state->config.name == c.name ? "' with other settings" : "'") +
                    "); reconstruct the portrait again with this model, or pass the --checkpoint it was made with");
  }
  if (state->model_id != model_id) {
    throw ModelLoad(file + ": the avatar was made with model '" + state->model_id + "' but this session runs '" +
                    model_id +
                    "'; reconstruct the portrait again with this model, or pass the --checkpoint it was made with");
  }
  const std::vector<int64_t> plane_shape = {1, 3, c.plane_channels, c.plane_size(), c.plane_size()};
  state->canonical = archive.Get("avatar.canonical", file);
  state->appearance = archive.Get("avatar.appearance", file);
  for (const torch::Tensor* t : {&state->canonical, &state->appearance}) {
    if (t->sizes() != plane_shape || t->scalar_type() != torch::kFloat32) {
      std::ostringstream why;
      why << file << ": avatar planes have shape " << t->sizes() << ", expected " << c10::IntArrayRef(plane_shape);
      throw ModelLoad(why.str());
    }
  }
  state->base = state->canonical + state->appearance;
  const torch::Tensor& src = archive.Get("avatar.source_image", file);
  if (src.dim() != 3 || src.size(2) != 3 || src.scalar_type() != torch::kUInt8) {
    throw ModelLoad(file + ": avatar source image is malformed");
  }
  state->source =
      cv::Mat(static_cast<int>(src.size(0)), static_cast<int>(src.size(1)), CV_8UC3, const_cast<void*>(src.data_ptr()))
          .clone();
  const torch::Tensor& bytes = archive.Get("avatar.expression_source", file);
  if (!kind.empty()) {
    const ExpressionSourceLoader loader = FindExpressionSourceLoader(kind);
    if (loader == nullptr) throw ModelLoad(file + ": unknown expression source '" + kind + "' in this build");
    try {
      state->expressions =
          loader(std::string(static_cast<const char*>(bytes.data_ptr()), static_cast<size_t>(bytes.numel())));
    } catch (const Error& e) {
      throw ModelLoad(file + ": expression source could not be restored: " + e.what());
    }
  }
  state->id = NextAvatarId();
  return state;
}

AvatarFileInfo ReadAvatarFileInfo(const std::filesystem::path& path) {
  const TensorArchive archive = ReadTensorArchive(path, "goha-avatar");
  AvatarFileInfo info;
  try {
    info.model_id = archive.meta.at("model_id").get<std::string>();
    info.config_name = archive.meta.at("config").at("name").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(path.string() + ": avatar metadata is incomplete: " + e.what());
  }
  return info;
}

}  // namespace avatar
