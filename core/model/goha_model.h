#pragma once
// The GOHA network (Li et al., NeurIPS 2023): three tri-plane branches, the shared volume
// renderer and tri-plane decoder, and the super-resolution module.
//
//   T_c = Embed2Plane_c(E_c(I_s))                                  canonical (neutral) planes
//   D_s, I_c = R_V(T_c, C_s) at feature_size^2                     depth + canonical render
//   F = E_p([I_s with eyes/mouth replaced by I_c, I_c])            6-channel appearance encoder
//   P = o + D_s d for foreground rays (matte >= 0.5), T_p = per-plane Upsampler(Rasterize(P, F))
//   T_e = Embed2Plane_e(E_e(I_exp))                                expression planes
//   I = R_V(T_c + T_p + T_e, C_t),  I_hr = SR(I)
// Ablation variants (ModelConfig): appearance_branch false -> T_p = 0; expression_model "bases"
// -> T_e = sum_k (beta_k / std_k) B_k from the target's morphable expression coefficients beta.
// Depth for lifting comes from T_c alone, as the paper describes (the release uses T_c + T_e),
// so T_p depends only on the source and is cached per avatar.
//
// Images are [B,3,S,S] float in [-1,1] (RGB); masks [B,1,S,S] in [0,1]; cameras are
// render::Cameras (EG3D 25-float labels). Every call increments a counter in counters() so
// that callers (and tests) can see which modules ran. The model is safe to use from several
// threads at once for inference (forward passes only read parameters).

#include <atomic>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/model/checkpoint.h"
#include "core/model/image_encoder.h"
#include "core/model/model_config.h"
#include "core/model/super_resolution.h"
#include "core/model/triplane_decoder.h"
#include "core/render/occupancy_grid.h"
#include "core/render/renderer.h"

namespace avatar {

// Embed2Plane: [B,D,h,w] -> planes [B,3,C,2h,2w]: conv3 D->W, conv3 W->M, ConvT(M,M,4,2,1),
// conv3 M->M (each followed by LeakyReLU 0.2), conv3 M->3C.
class Embed2PlaneImpl : public torch::nn::Module {
 public:
  Embed2PlaneImpl(int64_t in, int64_t width, int64_t mid, int64_t plane_channels);
  torch::Tensor forward(const torch::Tensor& x);
  double Flops(int64_t h, int64_t w) const;

 private:
  torch::nn::Conv2d conv1_{nullptr}, conv2_{nullptr}, conv4_{nullptr}, conv5_{nullptr};
  torch::nn::ConvTranspose2d up_{nullptr};
  int64_t in_, width_, mid_, channels_;
};
TORCH_MODULE(Embed2Plane);

// Appearance upsampler for one plane: [B,D,G,G] -> [B,C,2G,2G] =
// conv1x1(bilinear x2 input) + conv3(LReLU(ConvT(D->U,4,2,1))).
class PlaneUpsamplerImpl : public torch::nn::Module {
 public:
  PlaneUpsamplerImpl(int64_t in, int64_t width, int64_t out);
  torch::Tensor forward(const torch::Tensor& x);
  double Flops(int64_t h, int64_t w) const;

 private:
  torch::nn::Conv2d shortcut_{nullptr}, conv_{nullptr};
  torch::nn::ConvTranspose2d up_{nullptr};
  int64_t in_, width_, out_;
};
TORCH_MODULE(PlaneUpsampler);

// How many times each module ran (monotonic; reset with Reset()).
struct ModelCounters {
  std::atomic<int64_t> canonical_encoder{0};   // E_c + its head
  std::atomic<int64_t> appearance_encoder{0};  // E_p
  std::atomic<int64_t> expression_encoder{0};  // E_e + its head
  std::atomic<int64_t> rasterizations{0};      // lifting + rasterization + upsamplers
  std::atomic<int64_t> renders{0};             // volume renders (any size)
  std::atomic<int64_t> super_resolutions{0};   // SR passes
  void Reset();
};

// Intermediate results of the appearance branch.
struct AppearanceOutput {
  torch::Tensor planes;         // T_p [B,3,C,P,P]
  torch::Tensor canonical_rgb;  // I_c [B,3,G,G] in [-1,1] at the source camera (G = feature_size)
  torch::Tensor depth;          // D_s [B,1,G,G]
  torch::Tensor foreground;     // [B,G*G] bool: rays lifted into the point cloud
  torch::Tensor points;         // [B,G*G,3] lifted points (all rays)
};

// How GohaModel builds its encoders.
struct GohaModelOptions {
  // encoder mobilenet_v2: load nsfwjs's MobileNetV2 weights into the three backbones at
  // construction (their decode heads and every other module stay randomly initialised). A
  // missing, truncated or foreign model file throws ModelLoad naming it and scripts/setup.
  // Off = random backbones, no data folder needed: for a model whose tensors are loaded from a
  // checkpoint right after (LoadModelCheckpoint does this). No effect for mit_b0.
  bool pretrained = true;
  // Data folder holding models/nsfwjs ("" = the default resolution, AVATAR_DATA_DIR).
  std::string data_dir;
};

class GohaModelImpl : public torch::nn::Module {
 public:
  explicit GohaModelImpl(const ModelConfig& config, const GohaModelOptions& options = {});

  const ModelConfig& config() const { return config_; }
  ModelCounters& counters() const { return counters_; }

  // I_s [B,3,S,S] in [-1,1] -> T_c [B,3,C,P,P].
  torch::Tensor CanonicalPlanes(const torch::Tensor& image);
  // I_exp [B,3,S,S] in [-1,1] -> T_e [B,3,C,P,P] (expression_model "encoder"; a "bases" model
  // throws InvalidInput: it takes coefficients).
  torch::Tensor ExpressionPlanes(const torch::Tensor& expression_image);
  // Morphable expression coefficients beta [B,K] -> T_e = sum_k (beta_k / std_k) B_k [B,3,C,P,P]
  // (expression_model "bases"; an "encoder" model throws InvalidInput).
  torch::Tensor ExpressionPlanesFromCoefficients(const torch::Tensor& coefficients);
  // T_e by this model's expression_model: from I_exp (encoder) or from beta (bases); the other
  // input may be undefined.
  torch::Tensor ExpressionPlanesFor(const torch::Tensor& expression_image, const torch::Tensor& coefficients);
  // Sets std_k of the bases' coefficient scaling (K positive values; a fresh bases model has
  // ones). Trainers set it once from the morphable model that made the data; files keep it.
  void SetExpressionStd(const std::vector<float>& std_per_coefficient);
  // source [B,3,S,S] in [-1,1], eye_mouth [B,1,S,S] (1 = eyes/brows/lips/inner mouth), matte
  // [B,1,S,S] in [0,1], T_c, source cameras (B) -> T_p and intermediates. The canonical render
  // and depth are inputs of E_p and carry no gradient; gradients reach E_p and the upsamplers.
  // Without an appearance branch (config.appearance_branch false) only `planes` is set: zeros.
  AppearanceOutput AppearancePlanes(const torch::Tensor& source, const torch::Tensor& eye_mouth,
                                    const torch::Tensor& matte, const torch::Tensor& canonical_planes,
                                    const render::Cameras& cameras);
  // Volume render of planes [B,3,C,P,P] with this model's decoder; `resolution` 0 = config.render_size.
  render::RenderOutput Render(const torch::Tensor& planes, const render::Cameras& cameras, int resolution = 0,
                              bool deterministic = true, render::RenderProfile* profile = nullptr);
  // The same with explicit options (e.g. RenderOptionsFor with other sample counts); the skips
  // below apply as in Render.
  render::RenderOutput RenderWith(const torch::Tensor& planes, const render::Cameras& cameras,
                                  render::RenderOptions options, render::RenderProfile* profile = nullptr);
  // Render options of this config at `resolution` (0 = config.render_size).
  render::RenderOptions RenderOptionsFor(int resolution = 0, bool deterministic = true) const;
  // Render() turns on RenderOptions::EnableInferenceSkips (early termination, missed rays, empty
  // space) when set; they act only with grad mode off. Off by default (training and
  // reconstruction); the session passes its own per-frame options instead (session.h).
  bool inference_skips = false;
  // The occupancy grid of planes [B,3,C,P,P] under this model's decoder (empty-space skipping;
  // core/render/occupancy_grid.h). RenderWith builds one when options ask for empty-space
  // skipping without a grid and grad mode is off; callers that render the same planes often
  // (the session) build it once and pass it in RenderOptions::occupancy.
  std::shared_ptr<const render::OccupancyGrid> OccupancyGridFor(
      const torch::Tensor& planes, const render::OccupancyGridOptions& options = {}) const;
  // rgb [B,3,r,r] in [-1,1] -> [B,3,sr_size,sr_size].
  torch::Tensor SuperResolve(const torch::Tensor& rgb);

  // Named parts for inspection and gradient checks.
  // SegFormerEncoder (mit_b0) or MobileNetV2Encoder (mobilenet_v2), by config.encoder.
  ImageEncoder canonical_encoder{nullptr}, appearance_encoder{nullptr}, expression_encoder{nullptr};
  Embed2Plane canonical_head{nullptr}, expression_head{nullptr};
  std::vector<PlaneUpsampler> upsamplers;
  TriplaneDecoder decoder{nullptr};
  SuperResolution super_resolution{nullptr};
  // expression_model "bases" only (undefined otherwise): B [K,3,C,P,P] (parameter
  // "expression_bases", zeros at construction) and std [K] (buffer "expression_std").
  torch::Tensor expression_bases, expression_std;

  // Analytic FLOPs of one forward of every stage at this config, batch 1 (renders use the
  // decoder FLOPs per sample x samples; plane lookups and marching are not counted).
  std::vector<FlopEntry> Flops() const;

 private:
  // [-1,1] RGB -> the encoder's input: ImageNet mean/std for mit_b0; unchanged for
  // mobilenet_v2 (Keras MobileNetV2 takes [-1,1]).
  torch::Tensor Normalise(const torch::Tensor& rgb) const;
  ModelConfig config_;
  mutable ModelCounters counters_;
};
TORCH_MODULE(GohaModel);

// sum_k weights[b,k] * bases[k] for weights [B,K] and bases [K,...] -> [B,...] (the linear
// expression branch's mixing).
torch::Tensor MixExpressionBases(const torch::Tensor& weights, const torch::Tensor& bases);

// The density part of the decoder with its effective weights (occupancy bounds).
render::DensityMlp DecoderDensityMlp(const TriplaneDecoder& decoder);

// Parameters of a module (count).
int64_t CountParameters(const torch::nn::Module& module);

// Model checkpoints (kind "goha-model"): config + every parameter and buffer + CheckpointInfo.
// half_precision: floating tensors are stored as float16 (shipping weights; LoadModelCheckpoint
// widens them to the model's type).
void SaveModelCheckpoint(const std::filesystem::path& path, GohaModel& model, const CheckpointInfo& info,
                         bool half_precision = false);
struct LoadedModel {
  GohaModel model{nullptr};
  CheckpointInfo info;
};
// Builds the model from the stored config and loads every tensor, checking names and shapes.
// Throws Io (missing file) or ModelLoad (foreign, truncated, corrupt, or inconsistent file).
// `fingerprint` (optional) receives the file's checksum in hex: an id of exactly these weights.
LoadedModel LoadModelCheckpoint(const std::filesystem::path& path, std::string* fingerprint = nullptr);
// Copies the archive's tensors into `model` (names and shapes must match exactly).
void LoadModelTensors(GohaModel& model, const TensorArchive& archive, const std::string& source);

}  // namespace avatar
