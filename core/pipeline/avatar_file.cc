#include "core/pipeline/avatar_file.h"

#include <sstream>

#include <nlohmann/json.hpp>

#include "core/model/checkpoint.h"
#include "core/pipeline/avatar_file_info.h"
#include "core/util/error.h"

namespace avatar {
namespace {

torch::Tensor MatTensor(const cv::Mat& m, torch::ScalarType type) {
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  std::vector<int64_t> shape = {c.rows, c.cols};
  if (c.channels() > 1) shape.push_back(c.channels());
  return torch::from_blob(c.data, shape, type).clone();
}

cv::Mat TensorMat(const torch::Tensor& t, int type) {
  return cv::Mat(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), type, const_cast<void*>(t.data_ptr()))
      .clone();
}

void WritePortrait(const AvatarPortrait& p, TensorArchive* archive) {
  const morphable::FitResult& f = p.fit;
  archive->meta["portrait_fit"] = {{"alpha", f.alpha},
                                   {"beta", f.beta},
                                   {"scale", f.scale},
                                   {"camera", std::vector<float>(f.camera.begin(), f.camera.end())},
                                   {"image_size", {f.image_size.width, f.image_size.height}}};
  archive->tensors.emplace_back("portrait.unmatted", MatTensor(p.portrait.image_unmatted, torch::kUInt8));
  archive->tensors.emplace_back("portrait.matte", MatTensor(p.portrait.matte, torch::kFloat32));
  archive->tensors.emplace_back("portrait.eye_mouth", MatTensor(p.portrait.eye_mouth_mask, torch::kUInt8));
  std::vector<float> points;
  for (const cv::Point3f& q : p.portrait.landmarks.points) points.insert(points.end(), {q.x, q.y, q.z});
  archive->tensors.emplace_back(
      "portrait.landmarks",
      torch::tensor(points, torch::kFloat32).view({static_cast<int64_t>(p.portrait.landmarks.points.size()), 3}));
}

// The stored analysis, or null for files written before it was stored. Throws ModelLoad naming
// the file when it is there but damaged.
std::shared_ptr<const AvatarPortrait> ReadPortrait(const TensorArchive& archive, const std::string& file) {
  if (!archive.meta.contains("portrait_fit")) return nullptr;
  auto out = std::make_shared<AvatarPortrait>();
  try {
    const nlohmann::json& j = archive.meta.at("portrait_fit");
    const auto camera = j.at("camera").get<std::vector<float>>();
    const auto size = j.at("image_size").get<std::vector<int>>();
    if (camera.size() != 25 || size.size() != 2 || size[0] < 16 || size[1] < 16)
      throw ModelLoad(file + ": the stored portrait fit is malformed");
    morphable::CameraLabel label{};
    std::copy(camera.begin(), camera.end(), label.begin());
    out->fit = morphable::FitFromLabel(j.at("alpha").get<morphable::Alpha>(), j.at("beta").get<morphable::Beta>(),
                                       j.at("scale").get<float>(), label, cv::Size(size[0], size[1]));
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(file + ": the stored portrait fit is incomplete: " + e.what());
  }
  const torch::Tensor& crop = archive.Get("portrait.unmatted", file);
  const torch::Tensor& matte = archive.Get("portrait.matte", file);
  const torch::Tensor& eye_mouth = archive.Get("portrait.eye_mouth", file);
  const torch::Tensor& landmarks = archive.Get("portrait.landmarks", file);
  const int64_t h = out->fit.image_size.height, w = out->fit.image_size.width;
  if (crop.sizes() != c10::IntArrayRef({h, w, 3}) || crop.scalar_type() != torch::kUInt8 ||
      matte.sizes() != c10::IntArrayRef({h, w}) || matte.scalar_type() != torch::kFloat32 ||
      eye_mouth.sizes() != c10::IntArrayRef({h, w}) || eye_mouth.scalar_type() != torch::kUInt8 ||
      landmarks.dim() != 2 || landmarks.size(1) != 3 || landmarks.scalar_type() != torch::kFloat32) {
    throw ModelLoad(file + ": the stored portrait (crop, matte, masks, landmarks) is malformed");
  }
  if (!torch::isfinite(matte).all().item<bool>() || !torch::isfinite(landmarks).all().item<bool>())
    throw ModelLoad(file + ": the stored portrait holds non-finite values");
  out->portrait.image_unmatted = TensorMat(crop, CV_8UC3);
  out->portrait.matte = TensorMat(matte, CV_32FC1);
  out->portrait.eye_mouth_mask = TensorMat(eye_mouth, CV_8UC1);
  const torch::Tensor lm = landmarks.contiguous();
  const float* q = lm.data_ptr<float>();
  for (int64_t i = 0; i < lm.size(0); ++i) out->portrait.landmarks.points.emplace_back(q[3 * i], q[3 * i + 1], q[3 * i + 2]);
  return out;
}

}  // namespace

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
  if (s.portrait) WritePortrait(*s.portrait, &archive);
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
  state->portrait = ReadPortrait(archive, file);
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
