#include "core/pipeline/session.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <list>
#include <mutex>
#include <sstream>

#include <torch/torch.h>
#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/io/resources.h"
#include "core/model/checkpoint.h"
#include "core/model/goha_model.h"
#include "core/morphable/camera_label.h"
#include "core/pipeline/avatar_file.h"
#include "core/pipeline/avatar_state.h"
#include "core/io/image_tensor.h"
#include "core/pipeline/session_impl.h"
#include "core/pipeline/source_analysis.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/logging.h"

namespace avatar {

namespace {

std::mutex g_seed_mutex;  // torch::manual_seed is process-global

// The label must have passed render::CheckCameraLabel.
render::Cameras CamerasFromLabel(const std::array<float, 25>& label) {
  torch::Tensor t = torch::from_blob(const_cast<float*>(label.data()), {1, 25}, torch::kFloat32).clone();
  return render::CamerasFromLabels(t);
}

}  // namespace

RenderMode RenderModeFromName(const std::string& name) {
  if (name == "preview") return RenderMode::kPreview;
  if (name == "standard") return RenderMode::kStandard;
  if (name == "final") return RenderMode::kFinal;
  throw InvalidOptions("unknown render mode '" + name + "' (preview, standard or final)");
}

const char* RenderModeName(RenderMode mode) {
  switch (mode) {
    case RenderMode::kPreview:
      return "preview";
    case RenderMode::kStandard:
      return "standard";
    case RenderMode::kFinal:
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

void RenderSettings::Validate() const {
  AVATAR_CHECK_OPTION(resolution == 0 || (resolution >= 4 && resolution <= 1024))
      << "render resolution must be 0 (the model's) or 4..1024, got " << resolution;
  AVATAR_CHECK_OPTION(num_coarse == 0 || (num_coarse >= 2 && num_coarse <= 512))
      << "coarse samples per ray must be 0 (the model's) or 2..512, got " << num_coarse;
  AVATAR_CHECK_OPTION(num_importance >= -1 && num_importance <= 512)
      << "importance samples per ray must be -1 (the model's), 0 (none) or 1..512, got " << num_importance;
}

cv::Mat Avatar::SourceImage() const { return state_ ? state_->source.clone() : cv::Mat(); }

std::vector<std::string> Avatar::ControlNames() const {
  return state_ && state_->expressions ? state_->expressions->ControlNames() : std::vector<std::string>{};
}

int Avatar::CoefficientCount() const {
  return state_ && state_->expressions ? state_->expressions->CoefficientCount() : 0;
}

std::array<float, 25> Avatar::SourceCamera() const { return state_ ? state_->camera : std::array<float, 25>{}; }

std::string Avatar::RefinementInfo() const { return state_ ? state_->refinement : std::string(); }
bool Avatar::HasPortraitAnalysis() const { return state_ && state_->portrait != nullptr; }


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
    impl_->info.model_id = RandomModelId(options.config, options.seed);
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
    render::CheckCameraLabel(fit.camera);
    const render::Cameras cameras = CamerasFromLabel(fit.camera);
    auto state = std::make_shared<AvatarState>();
    state->config = c;
    state->model_id = impl_->info.model_id;
    state->id = NextAvatarId();
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
  return ReconstructFromAnalysis(analysis, ctx);
}

Avatar Session::ReconstructFromAnalysis(const SourceAnalysis& analysis, RunContext& ctx) const {
  Avatar avatar = ReconstructFromAnalysis(analysis.portrait, analysis.fit, ctx);
  auto state = std::make_shared<AvatarState>(*avatar.state_);  // the planes are shared, not copied
  auto kept = std::make_shared<AvatarPortrait>();
  kept->portrait = analysis.portrait;
  kept->portrait.embedding.clear();
  kept->fit = analysis.morphable_fit;
  state->portrait = std::move(kept);
  avatar.state_ = std::move(state);
  return avatar;
}

Frame Session::Animate(const Avatar& avatar, const Expression& expression, const ViewPose& view, RenderMode mode,
                       RunContext* ctx) const {
  return Animate(avatar, expression, render::CameraForView(view, morphable::FrontalLabel()), mode, ctx);
}

Frame Session::Animate(const Avatar& avatar, const Expression& expression, const std::array<float, 25>& camera,
                       RenderMode mode, RunContext* ctx) const {
  return Animate(avatar, expression, camera, RenderSettingsFor(mode, impl_->model->config().render_size), ctx);
}

RenderSettings RenderSettingsFor(RenderMode mode, int render_size) {
  RenderSettings settings;
  if (mode == RenderMode::kPreview) settings.resolution = std::min(64, render_size);
  settings.super_resolution = mode == RenderMode::kFinal;
  return settings;
}

Frame Session::Animate(const Avatar& avatar, const Expression& expression, const std::array<float, 25>& camera,
                       const RenderSettings& settings, RunContext* ctx) const {
  settings.Validate();
  AVATAR_CHECK_INPUT(avatar.valid()) << "Animate needs a reconstructed or loaded avatar";
  const AvatarState& state = *avatar.state_;
  AVATAR_CHECK_INPUT(state.model_id == impl_->info.model_id)
      << "this avatar was made with model '" << state.model_id << "', the session runs '" << impl_->info.model_id
      << "'; reconstruct it again with this model";
  try {
    torch::InferenceMode inference;
    render::CheckCameraLabel(camera);  // Throws InvalidInput for a label that is not a rigid camera.
    const render::Cameras cameras = CamerasFromLabel(camera);
    GohaModel& model = impl_->model;
    const ModelConfig& c = model->config();
    if (ctx != nullptr) ctx->ThrowIfCancelled();
    const std::shared_ptr<Impl::CachedPlanes> cached = impl_->PlanesFor(state, expression, ctx);
    const torch::Tensor& planes = cached->planes;
    if (ctx != nullptr) ctx->Report("animate", 0.3, "volume render");
    const int resolution = settings.resolution > 0 ? settings.resolution : c.render_size;
    render::RenderOptions ro = model->RenderOptionsFor(resolution);
    if (settings.num_coarse > 0) ro.num_coarse = settings.num_coarse;
    if (settings.num_importance >= 0) ro.num_importance = settings.num_importance;
    ro.return_opacity = settings.opacity;
    ro.return_depth = settings.depth;
    if (impl_->options.render_skips) {
      ro.early_termination = settings.early_termination;
      ro.skip_missed_rays = settings.skip_missed_rays;
      if (settings.skip_empty_space) {
        ro.occupancy = impl_->GridFor(*cached);
        ro.skip_empty_space = ro.occupancy != nullptr;
      }
    }
    const render::RenderOutput out = model->RenderWith(planes, cameras, ro);
    Frame frame;
    frame.render_size = resolution;
    // Random weights are a plumbing check of every module, the SR included.
    const bool run_sr = impl_->info.sr_trained || impl_->info.origin == "random";
    if (settings.super_resolution && run_sr) {
      if (ctx != nullptr) ctx->Report("animate", 0.7, "super-resolution");
      // The SR network takes renders of the model's render size.
      const torch::Tensor sr_input =
          resolution == c.render_size
              ? out.rgb
              : torch::nn::functional::interpolate(
                    out.rgb, torch::nn::functional::InterpolateFuncOptions()
                                 .size(std::vector<int64_t>{c.render_size, c.render_size})
                                 .mode(torch::kBilinear)
                                 .align_corners(false));
      frame.bgr = TensorToBgr(model->SuperResolve(sr_input));
      frame.super_resolved = true;
    } else if (settings.super_resolution) {
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
    if (out.opacity.defined()) frame.opacity = TensorToFloatMat(out.opacity, frame.bgr.rows);
    if (out.depth.defined()) frame.depth = TensorToFloatMat(out.depth, frame.bgr.rows);
    if (ctx != nullptr) ctx->Report("animate", 1.0, "done");
    return frame;
  } catch (...) {
    RethrowAsAvatarError("animate");
  }
}

void Session::SaveAvatar(const Avatar& avatar, const std::filesystem::path& path) const {
  AVATAR_CHECK_INPUT(avatar.valid()) << "cannot save an empty avatar";
  WriteAvatarFile(*avatar.state_, path);
}

Avatar Session::LoadAvatar(const std::filesystem::path& path) const {
  Avatar avatar;
  avatar.state_ = ReadAvatarFile(path, impl_->model->config(), impl_->info.model_id);
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

std::string RandomModelId(const std::string& config, int seed) {
  return "random:" + config + ":" + std::to_string(seed);
}

bool ParseRandomModelId(const std::string& model_id, std::string* config, int* seed) {
  if (model_id.rfind("random:", 0) != 0) return false;
  const size_t a = model_id.find(':'), b = model_id.rfind(':');
  if (b <= a + 1 || b + 1 >= model_id.size()) return false;
  try {
    size_t used = 0;
    const int value = std::stoi(model_id.substr(b + 1), &used);
    if (used != model_id.size() - b - 1) return false;
    if (seed != nullptr) *seed = value;
  } catch (const std::exception&) {
    return false;
  }
  if (config != nullptr) *config = model_id.substr(a + 1, b - a - 1);
  return true;
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
