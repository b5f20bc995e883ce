#pragma once
// SegFormer (Xie et al. 2021) encoder "Mix Transformer" (MiT) and its all-MLP decode head,
// written from the paper's description. GOHA uses MiT-b0 up to the decode head's 1x1 fuse
// convolution as the encoder of all three branches: a 3x512x512 image gives 256x128x128.
//
// Structure per stage s (widths C_s, depths, heads, spatial-reduction ratio R_s):
//   overlapping patch embedding: conv k7 s4 p3 (stage 0) or k3 s2 p1, then LayerNorm;
//   blocks: x += Attn(LN(x)); x += MixFFN(LN(x));
//     Attn: q = Wq x; keys/values from x reduced by a conv k=R_s s=R_s + LayerNorm (R_s > 1);
//           softmax(q k^T / sqrt(d)) v, output projection;
//     MixFFN: fc1 (C -> r C), depthwise 3x3 conv, GELU, fc2 (r C -> C);
//   a final LayerNorm; the stage output is reshaped to [B,C_s,H_s,W_s] (H_s = H / 2^(s+2)).
// Decode head: per stage a linear map C_s -> D, bilinear upsampling to H/4 (align_corners
// false), concatenation in the order stage 3,2,1,0, and a 1x1 conv 4D -> D without bias.
//
// FLOPs (multiply-add = 2 FLOPs, analytic): conv = 2 * Cin/groups * k^2 * Cout * Hout * Wout;
// linear = 2 * in * out per token; attention = 2 * N * Nr * C (scores) + 2 * N * Nr * C
// (weighted sum) with N tokens and Nr = N / R^2 reduced tokens; LayerNorm/GELU/softmax and
// interpolation are counted as 0 (below 1 % of the total at every size here).

#include <vector>

#include <torch/torch.h>

#include "core/model/image_encoder.h"
#include "core/model/model_config.h"

namespace avatar {


class OverlapPatchEmbedImpl : public torch::nn::Module {
 public:
  OverlapPatchEmbedImpl(int64_t in, int64_t out, int64_t kernel, int64_t stride);
  // x [B,in,H,W] -> tokens [B,N,out] with N = H' W'; writes H', W'.
  torch::Tensor forward(const torch::Tensor& x, int64_t* h, int64_t* w);
  double Flops(int64_t h_in, int64_t w_in) const;

 private:
  torch::nn::Conv2d proj_{nullptr};
  torch::nn::LayerNorm norm_{nullptr};
  int64_t in_, out_, kernel_, stride_;
};
TORCH_MODULE(OverlapPatchEmbed);

class EfficientAttentionImpl : public torch::nn::Module {
 public:
  EfficientAttentionImpl(int64_t dim, int64_t heads, int64_t sr_ratio);
  // x [B,N,C] with N = h*w -> [B,N,C]
  torch::Tensor forward(const torch::Tensor& x, int64_t h, int64_t w);
  double Flops(int64_t h, int64_t w) const;

 private:
  torch::nn::Linear q_{nullptr}, kv_{nullptr}, proj_{nullptr};
  torch::nn::Conv2d sr_{nullptr};
  torch::nn::LayerNorm sr_norm_{nullptr};
  int64_t dim_, heads_, sr_ratio_;
};
TORCH_MODULE(EfficientAttention);

class MixFfnImpl : public torch::nn::Module {
 public:
  MixFfnImpl(int64_t dim, int64_t hidden);
  torch::Tensor forward(const torch::Tensor& x, int64_t h, int64_t w);  // [B,N,C] -> [B,N,C]
  double Flops(int64_t h, int64_t w) const;

 private:
  torch::nn::Linear fc1_{nullptr}, fc2_{nullptr};
  torch::nn::Conv2d dw_{nullptr};
  int64_t dim_, hidden_;
};
TORCH_MODULE(MixFfn);

class MitBlockImpl : public torch::nn::Module {
 public:
  MitBlockImpl(int64_t dim, int64_t heads, int64_t sr_ratio, int64_t mlp_ratio);
  torch::Tensor forward(const torch::Tensor& x, int64_t h, int64_t w);  // [B,N,C] -> [B,N,C]
  double Flops(int64_t h, int64_t w) const;

 private:
  torch::nn::LayerNorm norm1_{nullptr}, norm2_{nullptr};
  EfficientAttention attn_{nullptr};
  MixFfn ffn_{nullptr};
};
TORCH_MODULE(MitBlock);

// MiT encoder + decode head up to the fuse conv. Input [B,in_channels,S,S] (S = config.image_size,
// already normalised), output [B,decoder_dim,S/4,S/4].
class SegFormerEncoderImpl : public ImageEncoderImpl {
 public:
  SegFormerEncoderImpl(const ModelConfig& config, int64_t in_channels);
  torch::Tensor forward(const torch::Tensor& x) override;
  // The four stage outputs [B,C_s,S/2^(s+2),S/2^(s+2)] (for tests and inspection).
  std::vector<torch::Tensor> Stages(const torch::Tensor& x);
  // Per-stage FLOPs ("stage0".."stage3", "head") for an S x S input, batch 1.
  std::vector<FlopEntry> Flops(int64_t size) const override;

 private:
  std::vector<OverlapPatchEmbed> embeds_;
  std::vector<std::vector<MitBlock>> blocks_;
  std::vector<torch::nn::LayerNorm> norms_;
  std::vector<torch::nn::Linear> head_linears_;
  torch::nn::Conv2d fuse_{nullptr};
  std::vector<int64_t> widths_;
  int64_t decoder_dim_;
};
TORCH_MODULE(SegFormerEncoder);


}  // namespace avatar
