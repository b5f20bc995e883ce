#pragma once
// Super-resolution module in the style of GFPGAN-v1-clean (Wang et al. 2021), written from
// the paper's description, and the dual discriminator of the second training stage.
//
// SuperResolution: the RGB render [B,3,r,r] in [-1,1] is resized (bilinear, align_corners
// false, as everywhere else) to S = sr_size and passed through
//   U-Net encoder: 1x1 conv 3 -> ch(S), residual down blocks S -> 4 (conv3, lrelu, x0.5, conv3,
//     lrelu; skip: x0.5 + 1x1 conv), a 3x3 conv and a linear layer giving one style vector per
//     decoder layer (w+, 2 log2(S) - 2 vectors of sr_style_dim);
//   U-Net decoder: residual up blocks 4 -> S with encoder skips; at each resolution two small
//     conv branches predict an SFT scale and shift for half of the StyleGAN2 channels;
//   StyleGAN2 decoder: constant 4x4 input, per resolution a modulated 3x3 conv after bilinear
//     x2 upsampling and a modulated 3x3 conv (weight demodulation, noise, bias, lrelu * sqrt 2),
//     SFT after the first one, and a modulated 1x1 toRGB added to the upsampled skip image.
// Noise: one fixed N(0,1) map per layer drawn once from a seeded generator and stored as a
// buffer (the release draws new noise per frame, which flickers); its scale is learned.
// Channels at resolution r: config.SrChannels(r) (= GFPGAN's table with channel multiplier 2
// for the paper config) in the StyleGAN2 decoder; the U-Net and the SFT branches run at half
// those widths, as GFPGANv1-clean does (86.4 M parameters at 512 for `paper`). The auxiliary per-scale RGB outputs of GFPGAN (used only by its
// restoration losses) are omitted.
//
// DualDiscriminator: input = concat(high-res image, low-res render upsampled to S) [B,6,S,S];
// StyleGAN2-style residual down blocks, minibatch standard deviation, conv, two linear layers
// -> one logit per image.

#include <vector>

#include <torch/torch.h>

#include "core/model/model_config.h"
#include "core/model/segformer.h"

namespace avatar {

class ModulatedConvImpl : public torch::nn::Module {
 public:
  ModulatedConvImpl(int64_t in, int64_t out, int64_t kernel, int64_t style_dim, bool demodulate, bool upsample);
  // x [B,in,H,W], style [B,style_dim] -> [B,out,H',W'] (H' = 2H when upsampling)
  torch::Tensor forward(const torch::Tensor& x, const torch::Tensor& style);
  double Flops(int64_t h_out, int64_t w_out) const;

 private:
  torch::nn::Linear modulation_{nullptr};
  torch::Tensor weight_;  // [out,in,k,k] stored N(0,1), scaled by 1/sqrt(in k k) at run time
  int64_t in_, out_, kernel_;
  bool demodulate_, upsample_;
};
TORCH_MODULE(ModulatedConv);

// Modulated conv + fixed noise * learned scale + bias + lrelu * sqrt(2).
class StyleConvImpl : public torch::nn::Module {
 public:
  StyleConvImpl(int64_t in, int64_t out, int64_t style_dim, bool upsample, int64_t resolution, uint64_t noise_seed);
  torch::Tensor forward(const torch::Tensor& x, const torch::Tensor& style);
  double Flops(int64_t h_out, int64_t w_out) const { return conv_->Flops(h_out, w_out); }

 private:
  ModulatedConv conv_{nullptr};
  torch::Tensor noise_;        // [1,1,R,R] buffer, fixed
  torch::Tensor noise_scale_;  // [1] parameter
  torch::Tensor bias_;         // [1,out,1,1]
};
TORCH_MODULE(StyleConv);

class ResBlockImpl : public torch::nn::Module {
 public:
  // mode: -1 down (x0.5), +1 up (x2).
  ResBlockImpl(int64_t in, int64_t out, int mode);
  torch::Tensor forward(const torch::Tensor& x);
  double Flops(int64_t h_in, int64_t w_in) const;

 private:
  torch::nn::Conv2d conv1_{nullptr}, conv2_{nullptr}, skip_{nullptr};
  int64_t in_, out_;
  int mode_;
};
TORCH_MODULE(ResBlock);

class SuperResolutionImpl : public torch::nn::Module {
 public:
  explicit SuperResolutionImpl(const ModelConfig& config);
  // rgb [B,3,r,r] in [-1,1] (any r) -> [B,3,S,S] (about [-1,1]).
  torch::Tensor forward(const torch::Tensor& rgb);
  std::vector<FlopEntry> Flops() const;  // "unet_encoder", "unet_decoder+sft", "stylegan_decoder"

 private:
  int64_t size_, num_levels_, style_dim_, num_latent_;
  std::vector<int64_t> channels_;  // channels_[l] at resolution 4 << l, l = 0..num_levels_-1
  std::vector<int64_t> unet_;      // U-Net/SFT widths: channels_[l] / 2 (GFPGANv1-clean)
  torch::nn::Conv2d first_{nullptr}, final_conv_{nullptr};
  torch::nn::Linear final_linear_{nullptr};
  std::vector<ResBlock> down_, up_;
  std::vector<torch::nn::Sequential> cond_scale_, cond_shift_;
  torch::Tensor const_input_;  // [1,ch4,4,4]
  StyleConv conv1_{nullptr};
  ModulatedConv to_rgb1_{nullptr};
  torch::Tensor to_rgb1_bias_;
  std::vector<StyleConv> convs_up_, convs_;
  std::vector<ModulatedConv> to_rgbs_;
  std::vector<torch::Tensor> to_rgb_biases_;
};
TORCH_MODULE(SuperResolution);

class DualDiscriminatorImpl : public torch::nn::Module {
 public:
  explicit DualDiscriminatorImpl(const ModelConfig& config);
  // high [B,3,S,S], low [B,3,r,r] (upsampled here) -> logits [B,1]
  torch::Tensor forward(const torch::Tensor& high, const torch::Tensor& low);
  double Flops() const;

 private:
  int64_t size_;
  std::vector<int64_t> channels_;
  torch::nn::Conv2d first_{nullptr}, final_conv_{nullptr};
  std::vector<ResBlock> blocks_;
  torch::nn::Linear fc1_{nullptr}, fc2_{nullptr};
};
TORCH_MODULE(DualDiscriminator);

// Bilinear resize with align_corners = false (the one convention used across the model).
torch::Tensor ResizeBilinear(const torch::Tensor& x, int64_t h, int64_t w);

}  // namespace avatar
