#pragma once
// MobileNetV2 (alpha 1.0) in LibTorch, following Keras' layer graph and names so that the
// ImageNet weights inside nsfwjs's TF.js layers model load one to one.
//
// Conventions kept from Keras: input [-1,1] (x/127.5-1 of 8-bit RGB), BatchNormalization with
// the topology's epsilon (1e-3) and always in inference form (frozen statistics, also in
// train()), ReLU6, depthwise 3x3 convolutions, and Keras' padding: stride-1 'same' pads one
// pixel on every side, while the stride-2 layers are preceded by explicit ZeroPadding2D layers
// in the topology (0 before, 1 after on each axis: asymmetric, as TF pads), which are read from
// the file. Kernels are converted from NHWC/HWIO to NCHW/OIHW on load.
//
// nsfwjs fine-tuned only block_11 onwards for its classifier: Conv1 .. block_10 are Keras'
// ImageNet weights (8-bit quantized), so the default network stops after block_10. Building
// later blocks (last_block > 10) loads nsfwjs's fine-tuned weights for them.

#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/io/keras_layers.h"
#include "core/model/image_encoder.h"

namespace avatar {

struct MobileNetV2Options {
  // Last inverted-residual block built (0 = expanded_conv ... 16); 10 = the ImageNet part.
  int last_block = 10;
  // BatchNormalization epsilon (replaced by the topology's on load).
  double bn_epsilon = 1e-3;
  // Input channels. The pretrained Conv1 takes RGB; for k*3 channels (E_p's 6) each RGB filter
  // is repeated per group of three and divided by k, so k copies of one image give the
  // pretrained response.
  int in_channels = 3;

  // Throws InvalidOptions.
  void Validate() const;
};

class MobileNetV2Impl : public torch::nn::Module {
 public:
  explicit MobileNetV2Impl(const MobileNetV2Options& options = {});

  // Copies weights, paddings and epsilon from a Keras MobileNetV2 layers model, checking that
  // every layer built here exists there with the same class, shape and stride. Throws ModelLoad
  // naming the model file.
  void LoadKeras(const io::KerasLayersModel& model);

  // x: [B,in_channels,H,W] in [-1,1] (any H, W >= 32). Returns the outputs of the Keras layers named in
  // `taps` (see TapNames), in that order; the forward stops at the last one needed.
  // Throws InvalidInput for an unknown tap or a bad input shape.
  std::vector<torch::Tensor> Features(const torch::Tensor& x, const std::vector<std::string>& taps) const;
  // The output of the last block built: [B,C,H/16,W/16] for last_block 10 (C = 96).
  torch::Tensor forward(const torch::Tensor& x) const;

  // Layer names usable as taps for the built blocks: "Conv1_relu", "expanded_conv_project_BN",
  // "block_N_expand_relu", "block_N_depthwise_relu", "block_N_project_BN" and, for residual
  // blocks, "block_N_add" (the block's output).
  std::vector<std::string> TapNames() const;
  // Output channels and stride (relative to the input) of a tap.
  int64_t TapChannels(const std::string& tap) const;
  int64_t TapStride(const std::string& tap) const;

  // Analytic FLOPs of forward() (every built block) for an h x w input, batch 1 (convolutions
  // only; BN, ReLU6 and the residual adds are not counted).
  double Flops(int64_t h, int64_t w) const;

  // Sets requires_grad(false) on every parameter (the network stays differentiable w.r.t. its input).
  void Freeze();

  const MobileNetV2Options& options() const { return options_; }

 private:
  // One Keras conv + BN pair (BN folded at run time with frozen statistics).
  struct ConvBn {
    std::string conv_name;  // Keras layer name of the convolution
    std::string bn_name;    // Keras layer name of its BatchNormalization
    torch::nn::Conv2d conv{nullptr};
    torch::nn::BatchNorm2d bn{nullptr};
    int64_t stride = 1;
    bool depthwise = false;
    std::vector<int64_t> pad;  // {left, right, top, bottom}
  };
  struct Block {
    int index = 0;       // 0 = expanded_conv
    std::string prefix;  // "expanded_conv" or "block_N"
    int64_t in = 0, out = 0, expand = 0, stride = 1;
    bool residual = false;
    ConvBn expand_conv;  // absent (conv empty) for block 0
    ConvBn depthwise;
    ConvBn project;
  };

  ConvBn MakeConvBn(const std::string& conv_name, const std::string& bn_name, int64_t in, int64_t out, int64_t kernel,
                    int64_t stride, bool depthwise);
  torch::Tensor Apply(const ConvBn& c, const torch::Tensor& x) const;
  void LoadConvBn(const io::KerasLayersModel& model, ConvBn& c);

  MobileNetV2Options options_;
  ConvBn stem_;
  std::vector<Block> blocks_;
};
TORCH_MODULE(MobileNetV2);

// MobileNetV2 encoder with a SegFormer-style all-MLP decode head, an alternative to the MiT-b0
// encoder: the outputs at 1/4, 1/8, 1/16 and 1/32 (block_2_add 24 ch, block_5_add 32 ch,
// block_12_add 96 ch, block_16_project_BN 320 ch) each go through a per-pixel linear map to
// decoder_dim channels, are upsampled bilinearly to 1/4 and fused by a 1x1 convolution:
// [B,in_channels,H,W] -> [B,decoder_dim,H/4,W/4], the map Embed2Plane takes. Pretrained weights:
// Conv1..block_10 ImageNet; block_11..block_16 are nsfwjs's fine-tuned continuation of the
// ImageNet weights (better than random, not ImageNet features). All parameters stay trainable;
// BatchNormalization keeps its pretrained statistics.
class MobileNetV2EncoderImpl : public ImageEncoderImpl {
 public:
  MobileNetV2EncoderImpl(int64_t in_channels, int64_t decoder_dim);
  // Loads the backbone from nsfwjs's layers model (the head stays randomly initialised).
  // Throws ModelLoad.
  void LoadKeras(const io::KerasLayersModel& model);
  torch::Tensor forward(const torch::Tensor& x) override;
  // "backbone" and "head" FLOPs for a size x size input, batch 1.
  std::vector<FlopEntry> Flops(int64_t size) const override;
  // The four backbone outputs [B,C_s,H/2^(s+2),W/2^(s+2)].
  std::vector<torch::Tensor> Stages(const torch::Tensor& x);
  static const std::vector<std::string>& StageTaps();

  MobileNetV2& Backbone() { return backbone_; }

 private:
  MobileNetV2 backbone_{nullptr};
  std::vector<torch::nn::Conv2d> head_linears_;
  torch::nn::Conv2d fuse_{nullptr};
  int64_t decoder_dim_;
};
TORCH_MODULE(MobileNetV2Encoder);

// The model file of nsfwjs's MobileNetV2 under the data folder ("" = default resolution).
std::filesystem::path NsfwjsMobileNetV2Path(const std::string& data_dir = {});

// Builds the network and loads nsfwjs's weights (from NsfwjsMobileNetV2Path(data_dir)), frozen
// and in eval mode. Throws ModelLoad naming the file and scripts/setup when it is missing,
// truncated or foreign.
MobileNetV2 LoadNsfwjsMobileNetV2(const std::string& data_dir = {}, const MobileNetV2Options& options = {});

}  // namespace avatar
