#include "core/model/super_resolution.h"

#include <cmath>
#include <string>

#include "core/util/error.h"

namespace avatar {

namespace F = torch::nn::functional;

namespace {

constexpr double kSqrt2 = 1.4142135623730951;

torch::Tensor Act(const torch::Tensor& x) {
  return F::leaky_relu(x, F::LeakyReLUFuncOptions().negative_slope(0.2)) * kSqrt2;
}

torch::nn::Conv2d SrConv(int64_t in, int64_t out, int64_t k, bool bias = true) {
  return torch::nn::Conv2d(torch::nn::Conv2dOptions(in, out, k).padding(k / 2).bias(bias));
}

int Log2(int64_t v) {
  int l = 0;
  while ((int64_t{1} << (l + 1)) <= v) ++l;
  return l;
}

}  // namespace

torch::Tensor ResizeBilinear(const torch::Tensor& x, int64_t h, int64_t w) {
  if (x.size(2) == h && x.size(3) == w) return x;
  return F::interpolate(
      x, F::InterpolateFuncOptions().size(std::vector<int64_t>{h, w}).mode(torch::kBilinear).align_corners(false));
}

ModulatedConvImpl::ModulatedConvImpl(int64_t in, int64_t out, int64_t kernel, int64_t style_dim, bool demodulate,
                                     bool upsample)
    : in_(in), out_(out), kernel_(kernel), demodulate_(demodulate), upsample_(upsample) {
  modulation_ = register_module("modulation", torch::nn::Linear(style_dim, in));
  {
    torch::NoGradGuard no_grad;
    modulation_->bias.fill_(1.0);  // styles start at 1: the layer starts as a plain conv
  }
  weight_ = register_parameter("weight", torch::randn({out, in, kernel, kernel}));
}

torch::Tensor ModulatedConvImpl::forward(const torch::Tensor& x, const torch::Tensor& style) {
  const int64_t b = x.size(0);
  const torch::Tensor s = modulation_->forward(style);  // [B,in]
  const double gain = 1.0 / std::sqrt(static_cast<double>(in_ * kernel_ * kernel_));
  torch::Tensor w = weight_.unsqueeze(0) * gain * s.view({b, 1, in_, 1, 1});  // [B,out,in,k,k]
  if (demodulate_) w = w * torch::rsqrt(w.pow(2).sum({2, 3, 4}, true) + 1e-8);
  torch::Tensor input = x;
  if (upsample_) input = ResizeBilinear(x, 2 * x.size(2), 2 * x.size(3));
  const int64_t h = input.size(2), wd = input.size(3);
  torch::Tensor y = F::conv2d(input.reshape({1, b * in_, h, wd}), w.reshape({b * out_, in_, kernel_, kernel_}),
                              F::Conv2dFuncOptions().padding(kernel_ / 2).groups(b));
  return y.view({b, out_, h, wd});
}

double ModulatedConvImpl::Flops(int64_t h_out, int64_t w_out) const {
  return ConvFlops(in_, out_, kernel_, h_out, w_out);
}

StyleConvImpl::StyleConvImpl(int64_t in, int64_t out, int64_t style_dim, bool upsample, int64_t resolution,
                             uint64_t noise_seed) {
  conv_ = register_module("conv", ModulatedConv(in, out, 3, style_dim, true, upsample));
  auto gen = at::detail::createCPUGenerator(noise_seed);
  noise_ = register_buffer("noise", at::randn({1, 1, resolution, resolution}, gen));
  noise_scale_ = register_parameter("noise_scale", torch::zeros({1}));
  bias_ = register_parameter("bias", torch::zeros({1, out, 1, 1}));
}

torch::Tensor StyleConvImpl::forward(const torch::Tensor& x, const torch::Tensor& style) {
  torch::Tensor y = conv_->forward(x, style);
  AVATAR_CHECK(y.size(2) == noise_.size(2)) << "style conv resolution mismatch";
  return Act(y + noise_scale_ * noise_ + bias_);
}

ResBlockImpl::ResBlockImpl(int64_t in, int64_t out, int mode) : in_(in), out_(out), mode_(mode) {
  conv1_ = register_module("conv1", SrConv(in, in, 3));
  conv2_ = register_module("conv2", SrConv(in, out, 3));
  skip_ = register_module("skip", SrConv(in, out, 1, false));
}

torch::Tensor ResBlockImpl::forward(const torch::Tensor& x) {
  const double factor = mode_ < 0 ? 0.5 : 2.0;
  const int64_t h = static_cast<int64_t>(x.size(2) * factor), w = static_cast<int64_t>(x.size(3) * factor);
  torch::Tensor y = F::leaky_relu(conv1_->forward(x), F::LeakyReLUFuncOptions().negative_slope(0.2));
  y = F::leaky_relu(conv2_->forward(ResizeBilinear(y, h, w)), F::LeakyReLUFuncOptions().negative_slope(0.2));
  return y + skip_->forward(ResizeBilinear(x, h, w));
}

double ResBlockImpl::Flops(int64_t h_in, int64_t w_in) const {
  const double factor = mode_ < 0 ? 0.5 : 2.0;
  const int64_t h = static_cast<int64_t>(h_in * factor), w = static_cast<int64_t>(w_in * factor);
  return ConvFlops(in_, in_, 3, h_in, w_in) + ConvFlops(in_, out_, 3, h, w) + ConvFlops(in_, out_, 1, h, w);
}

SuperResolutionImpl::SuperResolutionImpl(const ModelConfig& config)
    : size_(config.sr_size), style_dim_(config.sr_style_dim) {
  config.Validate();
  const int log_size = Log2(size_);
  num_levels_ = log_size - 1;  // resolutions 4, 8, ..., S
  num_latent_ = 2 * log_size - 2;
  for (int64_t l = 0; l < num_levels_; ++l) {
    channels_.push_back(config.SrChannels(static_cast<int>(4 << l)));
    // GFPGANv1-clean's U-Net and SFT branches run at half the StyleGAN widths (unet_narrow 0.5).
    unet_.push_back(std::max<int64_t>(1, channels_.back() / 2));
  }
  const int64_t top = num_levels_ - 1;

  first_ = register_module("unet_first", SrConv(3, unet_[top], 1));
  for (int64_t l = top; l >= 1; --l) {
    down_.push_back(register_module("unet_down" + std::to_string(4 << l), ResBlock(unet_[l], unet_[l - 1], -1)));
  }
  final_conv_ = register_module("unet_final_conv", SrConv(unet_[0], unet_[0], 3));
  final_linear_ = register_module("unet_final_linear", torch::nn::Linear(unet_[0] * 16, num_latent_ * style_dim_));
  for (int64_t l = 1; l <= top; ++l) {
    const std::string r = std::to_string(4 << l);
    up_.push_back(register_module("unet_up" + r, ResBlock(unet_[l - 1], unet_[l], +1)));
    // SFT modulates the upper half of the StyleGAN channels at this resolution.
    const int64_t half = channels_[l] - channels_[l] / 2;
    auto branch = [&](const std::string& name) {
      torch::nn::Sequential seq(SrConv(unet_[l], unet_[l], 3),
                                torch::nn::LeakyReLU(torch::nn::LeakyReLUOptions().negative_slope(0.2)),
                                SrConv(unet_[l], half, 3));
      return register_module(name + r, seq);
    };
    cond_scale_.push_back(branch("sft_scale"));
    cond_shift_.push_back(branch("sft_shift"));
  }

  const_input_ = register_parameter("const_input", torch::randn({1, channels_[0], 4, 4}));
  uint64_t seed = 0x5eed;
  conv1_ = register_module("conv1", StyleConv(channels_[0], channels_[0], style_dim_, false, 4, seed++));
  to_rgb1_ = register_module("to_rgb1", ModulatedConv(channels_[0], 3, 1, style_dim_, false, false));
  to_rgb1_bias_ = register_parameter("to_rgb1_bias", torch::zeros({1, 3, 1, 1}));
  for (int64_t l = 1; l <= top; ++l) {
    const std::string r = std::to_string(4 << l);
    convs_up_.push_back(
        register_module("conv_up" + r, StyleConv(channels_[l - 1], channels_[l], style_dim_, true, 4 << l, seed++)));
    convs_.push_back(
        register_module("conv" + r, StyleConv(channels_[l], channels_[l], style_dim_, false, 4 << l, seed++)));
    to_rgbs_.push_back(register_module("to_rgb" + r, ModulatedConv(channels_[l], 3, 1, style_dim_, false, false)));
    to_rgb_biases_.push_back(register_parameter("to_rgb_bias" + r, torch::zeros({1, 3, 1, 1})));
  }
}

torch::Tensor SuperResolutionImpl::forward(const torch::Tensor& rgb) {
  AVATAR_CHECK_INPUT(rgb.dim() == 4 && rgb.size(1) == 3)
      << "super-resolution input must be [B,3,H,W], got " << rgb.sizes();
  const int64_t b = rgb.size(0);
  torch::Tensor x = ResizeBilinear(rgb, size_, size_);  // [B,3,S,S]
  torch::Tensor feat = F::leaky_relu(first_->forward(x), F::LeakyReLUFuncOptions().negative_slope(0.2));
  std::vector<torch::Tensor> skips;  // resolutions S/2 ... 4
  for (auto& block : down_) {
    feat = block->forward(feat);
    skips.insert(skips.begin(), feat);
  }
  feat = F::leaky_relu(final_conv_->forward(feat), F::LeakyReLUFuncOptions().negative_slope(0.2));
  const torch::Tensor latent = final_linear_->forward(feat.flatten(1)).view({b, num_latent_, style_dim_});
  std::vector<torch::Tensor> scales, shifts;
  for (size_t i = 0; i < up_.size(); ++i) {
    feat = feat + skips[i];
    feat = up_[i]->forward(feat);
    scales.push_back(cond_scale_[i]->forward(feat));
    shifts.push_back(cond_shift_[i]->forward(feat));
  }

  torch::Tensor out = conv1_->forward(const_input_.expand({b, -1, -1, -1}), latent.select(1, 0));
  torch::Tensor image = to_rgb1_->forward(out, latent.select(1, 1)) + to_rgb1_bias_;  // [B,3,4,4]
  for (size_t i = 0; i < convs_.size(); ++i) {
    const int64_t l = static_cast<int64_t>(i) + 1;
    out = convs_up_[i]->forward(out, latent.select(1, 2 * l - 1));
    const int64_t same = out.size(1) / 2;
    const torch::Tensor kept = out.narrow(1, 0, same);
    const torch::Tensor modulated = out.narrow(1, same, out.size(1) - same) * scales[i] + shifts[i];
    out = torch::cat({kept, modulated}, 1);
    out = convs_[i]->forward(out, latent.select(1, 2 * l));
    const torch::Tensor skip = ResizeBilinear(image, out.size(2), out.size(3));
    image = skip + to_rgbs_[i]->forward(out, latent.select(1, 2 * l + 1)) + to_rgb_biases_[i];
  }
  return image;  // [B,3,S,S]
}

std::vector<FlopEntry> SuperResolutionImpl::Flops() const {
  double enc = ConvFlops(3, unet_.back(), 1, size_, size_);
  int64_t r = size_;
  for (const auto& block : down_) {
    enc += block->Flops(r, r);
    r /= 2;
  }
  enc += ConvFlops(unet_[0], unet_[0], 3, 4, 4) + 2.0 * unet_[0] * 16 * num_latent_ * style_dim_;
  double dec = 0.0;
  r = 4;
  for (size_t i = 0; i < up_.size(); ++i) {
    dec += up_[i]->Flops(r, r);
    r *= 2;
    const int64_t u = unet_[i + 1];
    const int64_t c = channels_[i + 1];
    dec += 2 * (ConvFlops(u, u, 3, r, r) + ConvFlops(u, c - c / 2, 3, r, r));
  }
  double sg = conv1_->Flops(4, 4) + to_rgb1_->Flops(4, 4);
  r = 4;
  for (size_t i = 0; i < convs_.size(); ++i) {
    r *= 2;
    sg += convs_up_[i]->Flops(r, r) + convs_[i]->Flops(r, r) + to_rgbs_[i]->Flops(r, r);
  }
  return {{"unet_encoder", enc}, {"unet_decoder+sft", dec}, {"stylegan_decoder", sg}};
}

DualDiscriminatorImpl::DualDiscriminatorImpl(const ModelConfig& config) : size_(config.sr_size) {
  config.Validate();
  const int levels = Log2(size_) - 1;
  for (int l = 0; l < levels; ++l) {
    const int64_t wanted = 16384L * config.sr_channel_multiplier / (4 << l);
    channels_.push_back(std::max<int64_t>(1, std::min<int64_t>(config.disc_max_channels, wanted)));
  }
  first_ = register_module("first", SrConv(6, channels_.back(), 1));
  for (int l = levels - 1; l >= 1; --l) {
    blocks_.push_back(register_module("down" + std::to_string(4 << l), ResBlock(channels_[l], channels_[l - 1], -1)));
  }
  final_conv_ = register_module("final_conv", SrConv(channels_[0] + 1, channels_[0], 3));
  fc1_ = register_module("fc1", torch::nn::Linear(channels_[0] * 16, channels_[0]));
  fc2_ = register_module("fc2", torch::nn::Linear(channels_[0], 1));
}

torch::Tensor DualDiscriminatorImpl::forward(const torch::Tensor& high, const torch::Tensor& low) {
  AVATAR_CHECK_INPUT(high.dim() == 4 && high.size(1) == 3 && high.size(2) == size_ && high.size(3) == size_)
      << "discriminator high-res input must be [B,3," << size_ << "," << size_ << "], got " << high.sizes();
  const auto lrelu = F::LeakyReLUFuncOptions().negative_slope(0.2);
  torch::Tensor x = torch::cat({high, ResizeBilinear(low, size_, size_)}, 1);  // [B,6,S,S]
  x = F::leaky_relu(first_->forward(x), lrelu);
  for (auto& block : blocks_) x = block->forward(x);  // [B,C4,4,4]
  // Minibatch standard deviation (one extra channel): spread of the batch around its mean.
  const torch::Tensor stddev = torch::sqrt(x.var(0, false) + 1e-8).mean().view({1, 1, 1, 1});
  x = torch::cat({x, stddev.expand({x.size(0), 1, 4, 4})}, 1);
  x = F::leaky_relu(final_conv_->forward(x), lrelu);
  x = F::leaky_relu(fc1_->forward(x.flatten(1)), lrelu);
  return fc2_->forward(x);  // [B,1]
}

double DualDiscriminatorImpl::Flops() const {
  double flops = ConvFlops(6, channels_.back(), 1, size_, size_);
  int64_t r = size_;
  for (const auto& block : blocks_) {
    flops += block->Flops(r, r);
    r /= 2;
  }
  flops +=
      ConvFlops(channels_[0] + 1, channels_[0], 3, 4, 4) + 2.0 * channels_[0] * 16 * channels_[0] + 2.0 * channels_[0];
  return flops;
}

}  // namespace avatar
