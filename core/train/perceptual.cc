#include "core/train/perceptual.h"

#include <set>

#include "core/util/error.h"

namespace avatar {
namespace {

// Block index of a tap name ("Conv1_relu" -> 0, "expanded_conv_*" -> 0, "block_N_*" -> N).
int TapBlock(const std::string& tap) {
  const std::string prefix = "block_";
  if (tap.rfind(prefix, 0) != 0) return 0;
  return std::stoi(tap.substr(prefix.size()));
}

}  // namespace

void PerceptualOptions::Validate() const {
  AVATAR_CHECK_OPTION(!taps.empty()) << "perceptual loss needs at least one tap";
  std::set<std::string> names = {"Conv1_relu", "expanded_conv_depthwise_relu", "expanded_conv_project_BN"};
  for (int n = 1; n <= 16; ++n) {
    for (const char* what : {"_expand_relu", "_depthwise_relu", "_project_BN", "_add"}) {
      names.insert("block_" + std::to_string(n) + what);
    }
  }
  for (const auto& t : taps) {
    AVATAR_CHECK_OPTION(names.count(t) > 0) << "perceptual loss: unknown MobileNetV2 tap '" << t << "'";
  }
}

PerceptualLoss::PerceptualLoss(const PerceptualOptions& options) : options_(options) {
  options_.Validate();
  MobileNetV2Options net_options;
  net_options.last_block = 0;
  for (const auto& t : options_.taps) net_options.last_block = std::max(net_options.last_block, TapBlock(t));
  net_ = LoadNsfwjsMobileNetV2(options_.data_dir, net_options);
}

PerceptualLoss::PerceptualLoss(MobileNetV2 net, const PerceptualOptions& options)
    : options_(options), net_(std::move(net)) {
  options_.Validate();
  AVATAR_CHECK_OPTION(!net_.is_empty()) << "perceptual loss: no network";
  net_->Freeze();
  net_->eval();
}

void PerceptualLoss::To(const torch::Device& device, torch::Dtype dtype) { net_->to(device, dtype); }

torch::Tensor PerceptualLoss::Distance(const torch::Tensor& a, const torch::Tensor& b,
                                       const torch::Tensor& mask) const {
  AVATAR_CHECK_INPUT(a.dim() == 4 && a.size(1) == 3) << "perceptual loss expects [B,3,H,W], got " << a.sizes();
  AVATAR_CHECK_INPUT(a.sizes() == b.sizes())
      << "perceptual loss: image shapes differ: " << a.sizes() << " vs " << b.sizes();
  if (mask.defined()) {
    AVATAR_CHECK_INPUT(mask.dim() == 4 && mask.size(0) == a.size(0) && mask.size(1) == 1 && mask.size(2) == a.size(2) &&
                       mask.size(3) == a.size(3))
        << "perceptual loss: mask must be [B,1,H,W] matching " << a.sizes() << ", got " << mask.sizes();
  }
  // Two separate passes with identical shapes give bitwise-equal features for equal images,
  // so the distance of an image to itself is exactly 0.
  return FeatureDistance(Features(a), Features(b), mask);
}

std::vector<torch::Tensor> PerceptualLoss::Features(const torch::Tensor& x) const {
  AVATAR_CHECK_INPUT(x.dim() == 4 && x.size(1) == 3) << "perceptual features expect [B,3,H,W], got " << x.sizes();
  return net_->Features(x, options_.taps);
}

torch::Tensor PerceptualLoss::FeatureDistance(const std::vector<torch::Tensor>& fa, const std::vector<torch::Tensor>& fb,
                                              const torch::Tensor& mask) const {
  AVATAR_CHECK_INPUT(!fa.empty() && fa.size() == fb.size()) << "perceptual loss: feature sets differ in length";
  torch::Tensor total = torch::zeros({fa[0].size(0)}, fa[0].options());
  for (size_t s = 0; s < fa.size(); ++s) {
    AVATAR_CHECK_INPUT(fa[s].sizes() == fb[s].sizes())
        << "perceptual loss: feature shapes differ: " << fa[s].sizes() << " vs " << fb[s].sizes();
    auto unit = [](const torch::Tensor& f) { return f * torch::rsqrt(f.pow(2).sum(1, /*keepdim=*/true) + 1e-10); };
    const torch::Tensor d = (unit(fa[s]) - unit(fb[s])).pow(2).sum(1, /*keepdim=*/true);  // [B,1,h,w]
    torch::Tensor stage;
    if (mask.defined()) {
      const torch::Tensor m = torch::adaptive_avg_pool2d(mask.to(d.dtype()), {d.size(2), d.size(3)});
      stage = (d * m).sum({1, 2, 3}) / (m.sum({1, 2, 3}) + 1e-8);
    } else {
      stage = d.mean({1, 2, 3});
    }
    total = total + stage;
  }
  return total / static_cast<double>(fa.size());
}

}  // namespace avatar
