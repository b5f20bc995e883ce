#include "core/pipeline/session.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <list>
#include <mutex>
#include <sstream>

#include <torch/torch.h>
#include <opencv2/imgproc.hpp>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/resources.h"
#include "core/model/checkpoint.h"
#include "core/model/goha_model.h"
#include "core/pipeline/session_access.h"
#include "core/pipeline/source_analysis.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {

// The cached per-source network state (see session.h).
struct AvatarState {
  ModelConfig config;
  std::string model_id;
  uint64_t id = 0;                 // unique within the process (cache key)
  torch::Tensor canonical;         // T_c [1,3,C,P,P]
  torch::Tensor appearance;        // T_p [1,3,C,P,P]
  torch::Tensor base;              // T_c + T_p
  std::array<float, 25> camera{};  // C_s
  cv::Mat source;                  // [512,512] CV_8UC3 aligned portrait
  std::shared_ptr<const ExpressionImageSource> expressions;
  std::string refinement;          // JSON summary of the refinement of these planes ("" = one-shot)
};

namespace {

std::atomic<uint64_t> g_next_avatar_id{1};
std::mutex g_seed_mutex;  // torch::manual_seed is process-global

std::map<std::string, ExpressionSourceLoader>& Loaders() {
  static std::map<std::string, ExpressionSourceLoader> loaders;
  return loaders;
}
std::mutex& LoadersMutex() {
  static std::mutex m;
  return m;
}

// BGR8 [H,W] -> RGB [1,3,size,size] in [-1,1].
torch::Tensor ImageToTensor(const cv::Mat& bgr, int size, const char* what) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << what << " must be a non-empty 8-bit BGR image";
  cv::Mat resized;
  if (bgr.rows != size || bgr.cols != size) {
    cv::resize(bgr, resized, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  } else {
    resized = bgr;
  }
  cv::Mat rgb;
  cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
  torch::Tensor t = torch::from_blob(rgb.data, {size, size, 3}, torch::kUInt8).clone();
  return t.permute({2, 0, 1}).unsqueeze(0).to(torch::kFloat32).div(127.5).sub(1.0);  // [1,3,S,S]
}

// Single-channel mask (8-bit 0..255 or float 0..1) -> [1,1,size,size] in [0,1]; `fill` when empty.
torch::Tensor MaskToTensor(const cv::Mat& mask, int size, float fill, const char* what) {
  if (mask.empty()) return torch::full({1, 1, size, size}, fill);
  AVATAR_CHECK_INPUT(mask.channels() == 1 && (mask.depth() == CV_8U || mask.depth() == CV_32F))
      << what << " must be a single-channel 8-bit or float image";
  cv::Mat f;
  mask.convertTo(f, CV_32F, mask.depth() == CV_8U ? 1.0 / 255.0 : 1.0);
  cv::resize(f, f, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  torch::Tensor t = torch::from_blob(f.data, {1, 1, size, size}, torch::kFloat32).clone();
  AVATAR_CHECK_INPUT(torch::isfinite(t).all().item<bool>()) << what << " has non-finite values";
  return t.clamp(0.0, 1.0);
}

// [1,3,H,W] in [-1,1] RGB -> BGR8.
cv::Mat TensorToBgr(const torch::Tensor& rgb) {
  torch::Tensor t = ((rgb[0].clamp(-1.0, 1.0) + 1.0) * 127.5).round().to(torch::kUInt8).permute({1, 2, 0}).contiguous();
  cv::Mat img(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_8UC3, t.data_ptr());
  cv::Mat bgr;
  cv::cvtColor(img, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

// [1,1,H,W] -> CV_32FC1 (resized bilinearly to `size` when it differs).
cv::Mat TensorToFloatMat(const torch::Tensor& x, int size) {
  torch::Tensor t = x[0][0].to(torch::kFloat32).contiguous();
  cv::Mat m(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_32FC1, t.data_ptr());
  cv::Mat out;
  if (m.rows != size) {
    cv::resize(m, out, cv::Size(size, size), 0, 0, cv::INTER_LINEAR);
  } else {
    out = m.clone();
  }
  return out;
}

render::Cameras CamerasFromLabel(const std::array<float, 25>& label) {
  for (float v : label) AVATAR_CHECK_INPUT(std::isfinite(v)) << "source camera label has non-finite values";
  torch::Tensor t = torch::from_blob(const_cast<float*>(label.data()), {1, 25}, torch::kFloat32).clone();
  return render::CamerasFromLabels(t);
}

std::string Hex(uint64_t v) {
  char buf[17];
  std::snprintf(buf, sizeof(buf), "%016llx", static_cast<unsigned long long>(v));
  return buf;
}

}  // namespace

std::string Expression::Key() const {
  std::ostringstream key;
  bool first = true;
  for (const auto& [name, value] : controls) {
    if (value == 0.0f) continue;  // an explicit 0 is the neutral value of every control
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%.6g", static_cast<double>(value));
    key << (first ? "" : ",") << name << "=" << buf;
    first = false;
  }
  return key.str();
}

bool RegisterExpressionSourceLoader(const std::string& kind, ExpressionSourceLoader loader) {
  std::lock_guard<std::mutex> lock(LoadersMutex());
  Loaders()[kind] = loader;
  return true;
}

Preset PresetFromName(const std::string& name) {
  if (name == "preview") return Preset::kPreview;
  if (name == "standard") return Preset::kStandard;
  if (name == "final") return Preset::kFinal;
  throw InvalidOptions("unknown preset '" + name + "' (preview, standard or final)");
}

const char* PresetName(Preset preset) {
  switch (preset) {
    case Preset::kPreview:
      return "preview";
    case Preset::kStandard:
      return "standard";
    case Preset::kFinal:
      return "final";
  }
  return "?";
}

void SessionOptions::Validate() const {
  ModelConfig::FromName(config);
  AVATAR_CHECK_OPTION(seed >= 0) << "--seed must be >= 0, got " << seed;
  AVATAR_CHECK_OPTION(expression_cache >= 1 && expression_cache <= 1024)
      << "--expression-cache must be 1..1024, got " << expression_cache;
}

cv::Mat Avatar::SourceImage() const { return state_ ? state_->source.clone() : cv::Mat(); }

std::vector<std::string> Avatar::ControlNames() const {
  return state_ && state_->expressions ? state_->expressions->ControlNames() : std::vector<std::string>{};
}

std::array<float, 25> Avatar::SourceCamera() const { return state_ ? state_->camera : std::array<float, 25>{}; }

std::string Avatar::RefinementInfo() const { return state_ ? state_->refinement : std::string(); }

struct Session::Impl {
  SessionOptions options;
  mutable GohaModel model{nullptr};  // forward passes only read parameters
  ModelInfo info;
  mutable std::mutex cache_mutex;
  // LRU of summed planes T_c + T_p + T_e keyed by "<avatar id>|<expression key>".
  mutable std::list<std::pair<std::string, torch::Tensor>> cache;
  mutable std::atomic<int64_t> expression_images{0};

  torch::Tensor PlanesFor(const AvatarState& state, const Expression& expression, RunContext* ctx) const {
    const std::string key = std::to_string(state.id) + "|" + expression.Key();
    {
      std::lock_guard<std::mutex> lock(cache_mutex);
      for (auto it = cache.begin(); it != cache.end(); ++it) {
        if (it->first == key) {
          cache.splice(cache.begin(), cache, it);
          return cache.front().second;
        }
      }
    }
    AVATAR_CHECK_INPUT(state.expressions != nullptr) << "this avatar has no expression source";
    const int s = model->config().image_size;
    if (ctx != nullptr) ctx->Report("animate", 0.1, "expression image");
    const cv::Mat exp_image = state.expressions->Render(expression, s);
    ++expression_images;
    AVATAR_CHECK(exp_image.type() == CV_8UC3 && exp_image.rows == s && exp_image.cols == s)
        << "expression source returned a " << exp_image.cols << "x" << exp_image.rows << " image, expected " << s;
    if (ctx != nullptr) ctx->Report("animate", 0.2, "expression planes");
    const torch::Tensor planes = state.base + model->ExpressionPlanes(ImageToTensor(exp_image, s, "I_exp"));
    std::lock_guard<std::mutex> lock(cache_mutex);
    cache.emplace_front(key, planes);
    while (static_cast<int>(cache.size()) > options.expression_cache) cache.pop_back();
    return planes;
  }
};

std::filesystem::path ResolveCheckpoint(const SessionOptions& options, std::string* origin) {
  const auto set = [&](const char* o) {
    if (origin != nullptr) *origin = o;
  };
  if (!options.checkpoint.empty()) {
    set("checkpoint");
    return options.checkpoint;
  }
  if (options.random_weights) {
    set("random");
    return {};
  }
  std::error_code ec;
  const std::filesystem::path installed = DataPaths::Resolve(options.data_dir).Path("models/goha.ckpt");
  if (std::filesystem::exists(installed, ec)) {
    set("installed");
    return installed;
  }
  const std::filesystem::path bundled = ResourcePath(kBundledModelFile);
  if (std::filesystem::exists(bundled, ec)) {
    set("bundled");
    return bundled;
  }
  std::string looked = installed.string();
  for (const auto& p : ResourceCandidates(kBundledModelFile)) looked += ", " + p.string();
  throw MissingData("No GOHA model found (looked for " + looked +
                    "). The bundled model ships in the package and the source tree's resources/models/; "
                    "reinstall the package, or pass --checkpoint FILE.");
}

std::string DescribeModel(const ModelInfo& info) {
  std::ostringstream out;
  if (info.origin == "random") {
    out << "UNTRAINED network with random weights (" << info.model_id << ", config " << info.config_name
        << "): not a result";
    return out.str();
  }
  const char* origin = info.origin == "bundled"     ? "bundled neural model"
                       : info.origin == "installed" ? "installed neural model"
                                                    : "neural model";
  out << origin << " " << info.model_id << " (config " << info.config_name << ", " << info.step
      << " training steps";
  if (!info.sr_trained) out << "; super-resolution not trained: upsampled";
  out << ")";
  if (info.origin != "bundled" && !info.checkpoint_path.empty()) out << " from '" << info.checkpoint_path << "'";
  return out.str();
}

Session::Session(const SessionOptions& options) : impl_(std::make_unique<Impl>()) {
  options.Validate();
  impl_->options = options;
  std::string origin;
  const std::filesystem::path checkpoint = ResolveCheckpoint(options, &origin);
  impl_->info.origin = origin;
  impl_->info.checkpoint_path = checkpoint.string();
  if (!checkpoint.empty()) {
    std::string fingerprint;
    LoadedModel loaded = LoadModelCheckpoint(checkpoint, &fingerprint);
    impl_->model = loaded.model;
    impl_->info.model_id = "ckpt:" + fingerprint;
    impl_->info.step = loaded.info.step;
    impl_->info.data_provenance = loaded.info.data_provenance;
    impl_->info.sr_trained = loaded.info.sr_trained;
  } else {
    std::lock_guard<std::mutex> lock(g_seed_mutex);
    torch::manual_seed(static_cast<uint64_t>(options.seed));
    impl_->model = GohaModel(ModelConfig::FromName(options.config));
    impl_->info.model_id = "random:" + options.config + ":" + std::to_string(options.seed);
    impl_->info.data_provenance = "random init (untrained)";
  }
  impl_->model->eval();
  const ModelConfig& c = impl_->model->config();
  impl_->info.config_name = c.name;
  impl_->info.config_json = ModelConfigToJson(c);
  impl_->info.parameters = CountParameters(*impl_->model);
  impl_->info.image_size = c.image_size;
  impl_->info.render_size = c.render_size;
  impl_->info.sr_size = c.sr_size;
}

Session::~Session() = default;

ModelInfo Session::Info() const { return impl_->info; }

Avatar Session::ReconstructFromAnalysis(const face::AlignedPortrait& portrait, const SourceFit& fit,
                                        RunContext& ctx) const {
  try {
    torch::InferenceMode inference;
    GohaModel& model = impl_->model;
    const ModelConfig& c = model->config();
    const int s = c.image_size;
    ctx.Report("reconstruct", 0.0, "canonical tri-plane");
    const torch::Tensor source = ImageToTensor(portrait.image, s, "aligned portrait");
    const torch::Tensor matte = MaskToTensor(portrait.matte, s, 1.0f, "matte");
    const torch::Tensor eye_mouth = MaskToTensor(portrait.eye_mouth_mask, s, 0.0f, "eye/mouth mask");
    const render::Cameras cameras = CamerasFromLabel(fit.camera);
    auto state = std::make_shared<AvatarState>();
    state->config = c;
    state->model_id = impl_->info.model_id;
    state->id = g_next_avatar_id++;
    state->canonical = model->CanonicalPlanes(source);
    ctx.Report("reconstruct", 0.4, "appearance tri-plane");
    const AppearanceOutput app = model->AppearancePlanes(source, eye_mouth, matte, state->canonical, cameras);
    state->appearance = app.planes;
    state->base = state->canonical + state->appearance;
    state->camera = fit.camera;
    cv::resize(portrait.image, state->source, cv::Size(512, 512), 0, 0, cv::INTER_AREA);
    state->expressions = fit.expressions;
    ctx.Report("reconstruct", 1.0, "done");
    Avatar avatar;
    avatar.state_ = state;
    return avatar;
  } catch (...) {
    RethrowAsAvatarError("reconstruct");
  }
}

Avatar Session::Reconstruct(const cv::Mat& bgr, RunContext& ctx) const {
  SourceAnalysis analysis;
  {
    RunContext::ProgressRange range(ctx, 0.0, 0.5);
    analysis = AnalyseSource(bgr, impl_->options.data_dir, ctx);
  }
  RunContext::ProgressRange range(ctx, 0.5, 1.0);
  return ReconstructFromAnalysis(analysis.portrait, analysis.fit, ctx);
}

Frame Session::Animate(const Avatar& avatar, const Expression& expression, const View& view, Preset preset,
                       RunContext* ctx) const {
  AVATAR_CHECK_INPUT(avatar.valid()) << "Animate needs a reconstructed or loaded avatar";
  const AvatarState& state = *avatar.state_;
  AVATAR_CHECK_INPUT(state.model_id == impl_->info.model_id)
      << "this avatar was made with model '" << state.model_id << "', the session runs '" << impl_->info.model_id
      << "'; reconstruct it again with this model";
  render::OrbitPose pose;
  pose.yaw = view.yaw;
  pose.pitch = view.pitch;
  pose.roll = view.roll;
  pose.radius = view.radius;
  pose.Validate();
  try {
    torch::InferenceMode inference;
    GohaModel& model = impl_->model;
    const ModelConfig& c = model->config();
    if (ctx != nullptr) ctx->ThrowIfCancelled();
    const torch::Tensor planes = impl_->PlanesFor(state, expression, ctx);
    if (ctx != nullptr) ctx->Report("animate", 0.3, "volume render");
    render::Cameras cameras{render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)};
    const int resolution = preset == Preset::kPreview ? std::min(64, c.render_size) : c.render_size;
    const render::RenderOutput out = model->Render(planes, cameras, resolution);
    Frame frame;
    frame.render_size = resolution;
    // Random weights are a plumbing check of every module, the SR included.
    const bool run_sr = impl_->info.sr_trained || impl_->info.origin == "random";
    if (preset == Preset::kFinal && run_sr) {
      if (ctx != nullptr) ctx->Report("animate", 0.7, "super-resolution");
      frame.bgr = TensorToBgr(model->SuperResolve(out.rgb));
      frame.super_resolved = true;
    } else if (preset == Preset::kFinal) {
      // Stage-I weights: the SR module is still at its initialisation, so its output would be
      // noise. Bicubic upsampling keeps the frame honest at the requested size.
      const torch::Tensor up = torch::nn::functional::interpolate(
          out.rgb, torch::nn::functional::InterpolateFuncOptions()
                       .size(std::vector<int64_t>{c.sr_size, c.sr_size})
                       .mode(torch::kBicubic)
                       .align_corners(false));
      frame.bgr = TensorToBgr(up);
      frame.upsampled = true;
    } else {
      frame.bgr = TensorToBgr(out.rgb);
    }
    frame.opacity = TensorToFloatMat(out.opacity, frame.bgr.rows);
    frame.depth = TensorToFloatMat(out.depth, frame.bgr.rows);
    if (ctx != nullptr) ctx->Report("animate", 1.0, "done");
    return frame;
  } catch (...) {
    RethrowAsAvatarError("animate");
  }
}

void Session::SaveAvatar(const Avatar& avatar, const std::filesystem::path& path) const {
  AVATAR_CHECK_INPUT(avatar.valid()) << "cannot save an empty avatar";
  const AvatarState& s = *avatar.state_;
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

Avatar Session::LoadAvatar(const std::filesystem::path& path) const {
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
  const ModelConfig& c = impl_->model->config();
  if (state->config != c) {
    throw ModelLoad(file + ": the avatar was made with model config '" + state->config.name +
                    "' (model '" + state->model_id + "') but this session runs '" + c.name +
                    "'; reconstruct the portrait again with this model, or pass the --checkpoint it was made with");
  }
  if (state->model_id != impl_->info.model_id) {
    throw ModelLoad(file + ": the avatar was made with model '" + state->model_id + "' but this session runs '" +
                    impl_->info.model_id +
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
    ExpressionSourceLoader loader = nullptr;
    {
      std::lock_guard<std::mutex> lock(LoadersMutex());
      auto it = Loaders().find(kind);
      if (it != Loaders().end()) loader = it->second;
    }
    if (loader == nullptr) throw ModelLoad(file + ": unknown expression source '" + kind + "' in this build");
    try {
      state->expressions =
          loader(std::string(static_cast<const char*>(bytes.data_ptr()), static_cast<size_t>(bytes.numel())));
    } catch (const Error& e) {
      throw ModelLoad(file + ": expression source could not be restored: " + e.what());
    }
  }
  state->id = g_next_avatar_id++;
  Avatar avatar;
  avatar.state_ = state;
  return avatar;
}

SessionCounters Session::Counters() const {
  const ModelCounters& m = impl_->model->counters();
  SessionCounters c;
  c.canonical_encoder = m.canonical_encoder;
  c.appearance_encoder = m.appearance_encoder;
  c.expression_encoder = m.expression_encoder;
  c.rasterizations = m.rasterizations;
  c.renders = m.renders;
  c.super_resolutions = m.super_resolutions;
  c.expression_images = impl_->expression_images;
  return c;
}

void Session::ResetCounters() const {
  impl_->model->counters().Reset();
  impl_->expression_images = 0;
}

GohaModel SessionAccess::Model(const Session& session) { return session.impl_->model; }

void SessionAccess::CheckAvatar(const Session& session, const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "refinement needs a reconstructed or loaded avatar";
  AVATAR_CHECK_INPUT(avatar.state_->model_id == session.impl_->info.model_id)
      << "this avatar was made with model '" << avatar.state_->model_id << "', the session runs '"
      << session.impl_->info.model_id << "'; reconstruct it again with this model";
}

torch::Tensor SessionAccess::Canonical(const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  return avatar.state_->canonical;
}

torch::Tensor SessionAccess::Appearance(const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  return avatar.state_->appearance;
}

torch::Tensor SessionAccess::ExpressionPlanes(const Session& session, const Avatar& avatar,
                                              const Expression& expression) {
  CheckAvatar(session, avatar);
  const AvatarState& state = *avatar.state_;
  if (state.expressions == nullptr) return {};
  torch::NoGradGuard no_grad;
  GohaModel& model = session.impl_->model;
  const int s = model->config().image_size;
  const cv::Mat image = state.expressions->Render(expression, s);
  ++session.impl_->expression_images;
  AVATAR_CHECK(image.type() == CV_8UC3 && image.rows == s && image.cols == s)
      << "expression source returned a " << image.cols << "x" << image.rows << " image, expected " << s;
  return model->ExpressionPlanes(ImageToTensor(image, s, "I_exp"));
}

Avatar SessionAccess::WithPlanes(const Avatar& avatar, const torch::Tensor& canonical,
                                 const torch::Tensor& appearance, const std::string& refinement_json) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  const AvatarState& old = *avatar.state_;
  for (const torch::Tensor* t : {&canonical, &appearance}) {
    AVATAR_CHECK_INPUT(t->defined() && t->sizes() == old.canonical.sizes())
        << "refined planes have shape " << (t->defined() ? t->sizes() : c10::IntArrayRef{}) << ", expected "
        << old.canonical.sizes();
    AVATAR_CHECK_INPUT(torch::isfinite(*t).all().item<bool>()) << "refined planes have non-finite values";
  }
  auto state = std::make_shared<AvatarState>(old);
  torch::NoGradGuard no_grad;
  state->canonical = canonical.detach().to(old.canonical.device(), torch::kFloat32).clone();
  state->appearance = appearance.detach().to(old.appearance.device(), torch::kFloat32).clone();
  state->base = state->canonical + state->appearance;
  state->refinement = refinement_json;
  state->id = g_next_avatar_id++;
  Avatar out;
  out.state_ = state;
  return out;
}

torch::Tensor SessionAccess::ImageTensor(const cv::Mat& bgr, int size, const char* what) {
  return ImageToTensor(bgr, size, what);
}

torch::Tensor SessionAccess::MaskTensor(const cv::Mat& mask, int size, float fill, const char* what) {
  return MaskToTensor(mask, size, fill, what);
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

face::AlignedPortrait PortraitFromAlignedImage(const cv::Mat& bgr) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "portrait must be a non-empty 8-bit BGR image";
  face::AlignedPortrait p;
  cv::resize(bgr, p.image, cv::Size(512, 512), 0, 0, cv::INTER_AREA);
  p.image_unmatted = p.image.clone();
  p.matte = cv::Mat(512, 512, CV_32FC1, cv::Scalar(1.0f));
  p.eye_mouth_mask = cv::Mat::zeros(512, 512, CV_8UC1);
  return p;
}

}  // namespace avatar
