#include "core/model/fusion_net.h"

#include "core/util/error.h"

namespace avatar {
namespace {

namespace nn = torch::nn;

nn::Sequential DoubleConv(int64_t in, int64_t out) {
  return nn::Sequential(nn::Conv2d(nn::Conv2dOptions(in, out, 3).padding(1)),
                        nn::LeakyReLU(nn::LeakyReLUOptions().negative_slope(0.2)),
                        nn::Conv2d(nn::Conv2dOptions(out, out, 3).padding(1)),
                        nn::LeakyReLU(nn::LeakyReLUOptions().negative_slope(0.2)));
}

constexpr double kMaskBias = -6.0;

}  // namespace

void FusionNetOptions::Validate() const {
  AVATAR_CHECK_OPTION(in_channels >= 1) << "the fusion net needs input channels, got " << in_channels;
  AVATAR_CHECK_OPTION(widths.size() >= 2) << "the fusion net needs at least two levels, got " << widths.size();
  for (int64_t w : widths) AVATAR_CHECK_OPTION(w >= 1 && w <= 1024) << "fusion net width " << w << " is outside 1..1024";
}

FusionNetImpl::FusionNetImpl(const FusionNetOptions& options) : options_(options) {
  options_.Validate();
  const auto& w = options_.widths;
  down_ = register_module("down", nn::ModuleList());
  pool_ = register_module("pool", nn::ModuleList());
  up_ = register_module("up", nn::ModuleList());
  int64_t in = options_.in_channels;
  for (size_t l = 0; l < w.size(); ++l) {
    down_->push_back(DoubleConv(in, w[l]));
    if (l + 1 < w.size()) pool_->push_back(nn::Conv2d(nn::Conv2dOptions(w[l], w[l], 3).stride(2).padding(1)));
    in = w[l];
  }
  for (size_t l = w.size() - 1; l-- > 0;) up_->push_back(DoubleConv(w[l + 1] + w[l], w[l]));
  head_ = register_module("head", nn::Conv2d(nn::Conv2dOptions(w[0], 4, 1)));
  torch::NoGradGuard no_grad;
  head_->weight.mul_(0.1);
  head_->bias.zero_();
  head_->bias[3].fill_(kMaskBias);
}

std::pair<torch::Tensor, torch::Tensor> FusionNetImpl::Heads(const torch::Tensor& x) {
  const int64_t levels = static_cast<int64_t>(options_.widths.size());
  const int64_t factor = int64_t{1} << (levels - 1);
  AVATAR_CHECK_INPUT(x.defined() && x.dim() == 4 && x.size(1) == options_.in_channels && x.size(2) % factor == 0 &&
                     x.size(3) % factor == 0 && x.size(2) > 0 && x.size(3) > 0)
      << "the fusion net takes [B," << options_.in_channels << ",H,W] with H and W divisible by " << factor
      << ", got " << x.sizes();
  std::vector<torch::Tensor> skips;
  torch::Tensor h = x;
  for (int64_t l = 0; l < levels; ++l) {
    h = down_[l]->as<nn::Sequential>()->forward(h);
    if (l + 1 < levels) {
      skips.push_back(h);
      h = pool_[l]->as<nn::Conv2d>()->forward(h);
    }
  }
  for (int64_t k = 0; k + 1 < levels; ++k) {
    const torch::Tensor& skip = skips[skips.size() - 1 - k];
    h = torch::nn::functional::interpolate(
        h, torch::nn::functional::InterpolateFuncOptions()
               .size(std::vector<int64_t>{skip.size(2), skip.size(3)})
               .mode(torch::kBilinear)
               .align_corners(false));
    h = up_[k]->as<nn::Sequential>()->forward(torch::cat({h, skip}, 1));
  }
  const torch::Tensor out = head_->forward(h);
  return {2.0 * torch::tanh(out.slice(1, 0, 3)), torch::sigmoid(out.slice(1, 3, 4))};
}

torch::Tensor FusionNetImpl::forward(const torch::Tensor& x) {
  const auto [residual, mask] = Heads(x);
  return x.slice(1, 0, 3) + mask * residual;
}

int64_t FusionNetImpl::ParameterCount() const {
  int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}

}  // namespace avatar
