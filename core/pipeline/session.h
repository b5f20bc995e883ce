#pragma once
// The Session: the one door through which the studio and the CLI's product commands use the GOHA
// network (the developer tools train, inspect and bench work on core/model directly).
//
//   Session session(options);                      // loads the model (or random weights on request)
//   Avatar avatar = session.Reconstruct(bgr, ctx); // face analysis, fit, T_c and T_p (cached in the avatar)
//   Frame f = session.Animate(avatar, {{{"jawOpen", 0.6f}}}, ViewPose{20, -5}, RenderMode::kPreview);
//   Frame g = session.Animate(avatar, expression, CameraForView(pose, avatar.SourceCamera()), mode);
//
// Expressions (expression.h) are morphable expression coefficients relative to the portrait's
// fitted expression (or absolute); the avatar's expression source renders I_exp from exactly
// those coefficients (ExpressionBeta), named controls being one way to write them.
//
// What Animate recomputes (instrumented by Counters()):
//   - a new view only: no encoder; one volume render of the cached planes T_c + T_p + T_e;
//   - a new expression: the morphable render I_exp and E_e (T_e), then the render (a network with
//     expression bases mixes T_e from the expression's morphable coefficients instead: no I_exp);
//   - super-resolution only for RenderMode::kFinal.
// Frames are rendered with the inference skips on (RenderSettings, SessionOptions::render_skips):
// early ray termination, rays missing the box, and empty-space skipping through an occupancy
// grid built once per cached T_c + T_p + T_e, at the second frame that renders those planes (so
// again after a new expression, a new reconstruction or a refinement, which makes a new avatar
// id; the first frame of a new expression never waits for a grid).
// T_p depends on the source alone because the lifting depth is rendered from T_c (paper).
//
// Thread safety: a Session may be used from several threads at once. Reconstruct and Animate
// only read the network's parameters (inference mode inside each call, so any worker thread
// works) and guard the session's expression cache with a mutex. An Avatar is immutable after
// Reconstruct/LoadAvatar and may be shared between threads (copies share the state).
// No LibTorch types appear in this header.

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/pipeline/avatar_file_info.h"
#include "core/pipeline/expression.h"
#include "core/pipeline/source_fit.h"
#include "core/render/view_pose.h"
#include "core/util/run_context.h"

namespace avatar {

// The project's one pose type (core/render/view_pose.h).
using render::ViewPose;

enum class RenderMode {
  kPreview,   // small render (min(64, render_size)), no super-resolution: interactive
  kStandard,  // the config's render size, no super-resolution
  kFinal,     // the config's render size + super-resolution to sr_size
};
// "preview", "standard", "final"; throws InvalidOptions otherwise.
RenderMode RenderModeFromName(const std::string& name);
const char* RenderModeName(RenderMode mode);

struct Frame {
  cv::Mat bgr;          // [H,W] CV_8UC3
  // Empty when RenderSettings::opacity / ::depth are off.
  cv::Mat opacity;      // [H,W] CV_32FC1 in [0,1] (bilinear-upsampled from the render for kFinal)
  cv::Mat depth;        // [H,W] CV_32FC1 expected depth along the ray (far plane 3.3 for empty rays)
  int render_size = 0;  // side of the volume render behind this frame
  bool super_resolved = false;
  // kFinal with a model whose super-resolution is untrained (stage-I weights): the render was
  // upsampled bicubically to sr_size instead (see ModelInfo::sr_trained).
  bool upsampled = false;
};

// Explicit settings of one frame's render. The quality ladder (quality.h) resolves its levels
// into these; each RenderMode is one of them (see Animate).
struct RenderSettings {
  int resolution = 0;             // side of the volume render (0 = the model's render size)
  int num_coarse = 0;             // stratified samples per ray (0 = the model's)
  int num_importance = -1;        // importance samples per ray (-1 = the model's; 0 = none)
  bool super_resolution = false;  // output at sr_size: the SR network when trained (or random weights), else bicubic
  // Inference skips of the volume render (core/render/renderer.h), each bounded in its change to
  // the image (docs/PERFORMANCE.md "Render skips", "Frame time with render skips"; skipping
  // missed rays assumes the field is empty outside the box, which a foggy model is not at views
  // wider than the default framing). They act only while SessionOptions::render_skips is on (the
  // default); all on by default.
  bool early_termination = true;  // stop marching a ray once its transmittance is below 1e-3
  bool skip_missed_rays = true;   // rays that miss the tri-plane box are background
  bool skip_empty_space = true;   // no decoder in cells the avatar's occupancy grid marks empty
  // Outputs: Frame::opacity / Frame::depth stay empty when off (the render skips their sums).
  bool opacity = true;
  bool depth = true;
  // Throws InvalidOptions (resolution outside 0 or 4..1024, coarse outside 0 or 2..512, importance outside -1..512).
  void Validate() const;
};
// The settings a RenderMode stands for with a model of this render size (Animate with a mode
// renders with them).
RenderSettings RenderSettingsFor(RenderMode mode, int render_size);

struct SessionOptions {
  // Model checkpoint (.ckpt). "" = <data dir>/models/goha.ckpt when the user installed one,
  // else the bundled default model (ResourcePath(kBundledModelFile), core/io/resources.h).
  std::string checkpoint;
  // Run the untrained network with random weights when no checkpoint is given (explicit opt-in).
  bool random_weights = false;
  // Config of the random-weight network: paper, lite or tiny (a checkpoint carries its own).
  std::string config = "lite";
  // Seed of the random weights (avatars remember it: they only load into the same weights).
  int seed = 0;
  // Folder with installed data ("" = AVATAR_DATA_DIR or the default cache).
  std::string data_dir;
  // Expression planes kept in the session's cache (LRU), each with its occupancy grid.
  int expression_cache = 16;
  // Render frames with the inference skips their RenderSettings ask for (all by default); off =
  // every sample of every ray is evaluated (the full render, for comparisons).
  bool render_skips = true;

  template <typename V>
  void Visit(V&& v) {
    v("checkpoint", checkpoint,
      "Model checkpoint file (default: <data dir>/models/goha.ckpt if installed, else the bundled model)");
    v("random_weights", random_weights, "Run the untrained network with random weights (no model installed)");
    v("config", config, "Network size with --random-weights: paper, lite or tiny");
    v("seed", seed, "Seed of the random weights");
    v("expression_cache", expression_cache, "Expression tri-planes kept in memory");
    v("render_skips", render_skips,
      "Skip work a frame does not need (early ray termination, rays missing the head's box, empty space); "
      "--no-render-skips renders every sample");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

// Times each module ran since the session started (or ResetCounters()).
struct SessionCounters {
  int64_t canonical_encoder = 0;
  int64_t appearance_encoder = 0;
  int64_t expression_encoder = 0;
  int64_t rasterizations = 0;
  int64_t renders = 0;
  int64_t super_resolutions = 0;
  int64_t expression_images = 0;  // morphable renders of I_exp
};

// Description of the loaded network (for inspect and the GUI's about box).
struct ModelInfo {
  std::string config_name;
  std::string config_json;
  std::string model_id;  // checkpoint fingerprint or "random:<config>:<seed>"
  int64_t parameters = 0;
  int64_t step = 0;
  std::string data_provenance;
  // Where the weights came from: "bundled", "installed" (<data dir>/models/goha.ckpt),
  // "checkpoint" (given explicitly) or "random".
  std::string origin;
  std::string checkpoint_path;  // "" for random weights
  bool sr_trained = false;      // false: kFinal upsamples the render instead of the untrained SR
  int image_size = 0, render_size = 0, sr_size = 0;
};

// One line naming the model for the user, e.g. "bundled neural model ckpt:0123... (config cpu,
// 804 training steps; super-resolution not trained: upsampled)". Every command that renders
// with the network prints it.
std::string DescribeModel(const ModelInfo& info);

// The model id of the random-weight network of `config` and `seed`: "random:<config>:<seed>"
// (ModelInfo::model_id; avatar files and the quality cache store it).
std::string RandomModelId(const std::string& config, int seed);
// The inverse: true and the config and seed for a random model id, false for a checkpoint's id.
bool ParseRandomModelId(const std::string& model_id, std::string* config, int* seed);

// The checkpoint a Session with these options loads ("" for random weights) and its origin
// (see ModelInfo::origin). Throws MissingData, saying where it looked, when there is none.
std::filesystem::path ResolveCheckpoint(const SessionOptions& options, std::string* origin = nullptr);

struct AvatarState;     // defined in avatar_state.h
struct SourceAnalysis;  // defined in source_analysis.h

// A reconstructed avatar: immutable, cheap to copy (shared state).
class Avatar {
 public:
  Avatar() = default;
  bool valid() const { return state_ != nullptr; }
  // The aligned source portrait (BGR 512 crop on black).
  cv::Mat SourceImage() const;
  // Expression controls the avatar's expression source understands.
  std::vector<std::string> ControlNames() const;
  // Length of Expression::coefficients the avatar's expression source understands (0 = none).
  int CoefficientCount() const;
  // The source camera label (25 floats).
  std::array<float, 25> SourceCamera() const;
  // JSON summary of the per-portrait refinement (core/pipeline/refine.h) these planes had, or ""
  // for the one-shot planes. Stored in avatar files.
  std::string RefinementInfo() const;
  // True when the avatar keeps its portrait's analysis (crop, matte, morphable fit): the photo's
  // detail path can render it. Avatars from Reconstruct and files written since 2026-12-05 do.
  bool HasPortraitAnalysis() const;
  const AvatarState* state() const { return state_.get(); }

 private:
  friend class Session;
  friend struct SessionAccess;  // core/pipeline/session_access.h (refinement)
  std::shared_ptr<const AvatarState> state_;
};

class Session {
 public:
  // Loads the checkpoint (or builds random weights when asked). Throws MissingData when no
  // model is installed and random weights were not requested, ModelLoad for a bad checkpoint,
  // InvalidOptions for bad options.
  explicit Session(const SessionOptions& options);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  ModelInfo Info() const;

  // The network part: T_c from the portrait, the lifting depth and T_p at the source camera.
  // Throws InvalidInput (bad portrait), Cancelled.
  Avatar ReconstructFromAnalysis(const face::AlignedPortrait& portrait, const SourceFit& fit, RunContext& ctx) const;
  // The same from a whole analysis; the avatar keeps the crop, matte and morphable fit the detail
  // path needs (Avatar::HasPortraitAnalysis), and avatar files store them.
  Avatar ReconstructFromAnalysis(const SourceAnalysis& analysis, RunContext& ctx) const;
  // Face analysis + morphable fit + ReconstructFromAnalysis. Throws InvalidInput (no face),
  // MissingData (face models not installed), Cancelled.
  Avatar Reconstruct(const cv::Mat& bgr, RunContext& ctx) const;

  // One frame at pose `view` about the frontal camera: CameraForView(view, C_front), a camera on a
  // sphere of radius 2.7 / zoom looking at the origin (for `render` and benchmarks; frame sources
  // pass CameraForView(pose, avatar.SourceCamera()) instead). Throws InvalidInput (invalid avatar,
  // unknown control, wrong coefficient count), InvalidOptions (bad pose), Cancelled.
  Frame Animate(const Avatar& avatar, const Expression& expression, const ViewPose& view, RenderMode mode,
                RunContext* ctx = nullptr) const;
  // One frame seen by `camera`, an EG3D label (25 floats: cam2world + normalised intrinsics),
  // e.g. CameraForView(pose, avatar.SourceCamera()); the avatar's SourceCamera() renders the
  // source view. Throws InvalidInput (as above, or a label that is not a rigid camera), Cancelled.
  Frame Animate(const Avatar& avatar, const Expression& expression, const std::array<float, 25>& camera,
                RenderMode mode, RunContext* ctx = nullptr) const;
  // The same with explicit render settings (kPreview = {min(64, render size)}, kStandard = {},
  // kFinal = {super_resolution}). Also throws InvalidOptions for bad settings.
  Frame Animate(const Avatar& avatar, const Expression& expression, const std::array<float, 25>& camera,
                const RenderSettings& settings, RunContext* ctx = nullptr) const;

  // Avatar files (.avatar, format in avatar_file.h): planes, camera, source image, expression
  // source, model id. Save throws Io; Load throws Io / ModelLoad (corrupt file, other model or config).
  void SaveAvatar(const Avatar& avatar, const std::filesystem::path& path) const;
  Avatar LoadAvatar(const std::filesystem::path& path) const;

  SessionCounters Counters() const;
  void ResetCounters() const;

  struct Impl;

 private:
  friend struct SessionAccess;  // core/pipeline/session_access.h (refinement)
  std::unique_ptr<Impl> impl_;
};

// BGR8 portrait -> AlignedPortrait-like input for callers that already have an aligned crop
// (tests, tools): resized to 512, matte all ones, empty eye/mouth mask.
face::AlignedPortrait PortraitFromAlignedImage(const cv::Mat& bgr);

}  // namespace avatar
