#pragma once
// Perceptual distance on ImageNet MobileNetV2 features (nsfwjs's Conv1..block_10), in the form
// of LPIPS without its learned channel weights: at each tapped stage the features of both
// images are unit-normalised over channels, their squared difference is summed over channels
// and averaged over space (mask-weighted when a mask is given); the stages are averaged with
// equal weights. It stands in for the paper's VGG/LPIPS terms; reports call it
// "perceptual (MobileNetV2)", never LPIPS.
//
// Default taps: the last ReLU6 activation at each resolution inside the ImageNet part:
//   block_1_expand_relu      1/2,   96 channels
//   block_3_expand_relu      1/4,  144 channels
//   block_6_expand_relu      1/8,  192 channels
//   block_10_depthwise_relu  1/16, 384 channels
// (the expand activations are the widest, rectified features before each stride-2 step; the
// linear bottleneck outputs carry fewer channels and no rectification.)

#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/model/mobilenet_v2.h"

namespace avatar {

struct PerceptualOptions {
  // MobileNetV2 layers whose outputs are compared (MobileNetV2Impl::TapNames()).
  std::vector<std::string> taps = {"block_1_expand_relu", "block_3_expand_relu", "block_6_expand_relu",
                                   "block_10_depthwise_relu"};
  // Data folder holding models/nsfwjs ("" = AVATAR_DATA_DIR or the default cache).
  std::string data_dir;

  // Throws InvalidOptions.
  void Validate() const;
};

class PerceptualLoss {
 public:
  // Name used in reports and logs.
  static constexpr const char* kReportName = "perceptual (MobileNetV2)";

  // Loads nsfwjs's MobileNetV2 up to the deepest tap. Throws ModelLoad naming the file and
  // scripts/setup when it is missing, truncated or foreign; InvalidOptions.
  explicit PerceptualLoss(const PerceptualOptions& options = {});
  // Uses an already built network (frozen here); for tests and shared backbones.
  PerceptualLoss(MobileNetV2 net, const PerceptualOptions& options);

  // a, b: [B,3,H,W] in [-1,1] (H, W >= 32); mask: undefined or [B,1,H,W] in [0,1] (area-averaged
  // to each stage's resolution, then a weighted spatial mean). Returns [B] distances >= 0, exactly
  // 0 where a == b. The network's weights are frozen; gradients flow to a and b.
  // Throws InvalidInput on shape mismatches.
  torch::Tensor Distance(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask = {}) const;
  // The same in two steps, for comparing many images or masks with features computed once:
  // Features(a) at the taps, then the distance of two feature sets under a mask (as above).
  std::vector<torch::Tensor> Features(const torch::Tensor& x) const;
  torch::Tensor FeatureDistance(const std::vector<torch::Tensor>& fa, const std::vector<torch::Tensor>& fb,
                                const torch::Tensor& mask = {}) const;

  // Moves the network to a device / dtype (double for gradient checks).
  void To(const torch::Device& device, torch::Dtype dtype = torch::kFloat32);

  const MobileNetV2& Network() const { return net_; }
  const PerceptualOptions& options() const { return options_; }

 private:
  PerceptualOptions options_;
  MobileNetV2 net_{nullptr};
};

}  // namespace avatar
