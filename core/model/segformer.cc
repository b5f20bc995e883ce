#include "core/model/segformer.h"

#include <cmath>
#include <string>

#include "core/util/error.h"

namespace avatar {

namespace F = torch::nn::functional;

double ConvFlops(int64_t in, int64_t out, int64_t kernel, int64_t h_out, int64_t w_out, int64_t groups) {
  return 2.0 * static_cast<double>(in / groups) * kernel * kernel * out * h_out * w_out;
}

namespace {

// Linear layers start from N(0, 0.02) with zero bias (SegFormer's initialisation).
torch::nn::Linear MakeLinear(int64_t in, int64_t out, bool bias = true) {
  torch::nn::Linear layer(torch::nn::LinearOptions(in, out).bias(bias));
  torch::NoGradGuard no_grad;
  layer->weight.normal_(0.0, 0.02);
  if (bias) layer->bias.zero_();
  return layer;
}

int64_t ConvOut(int64_t in, int64_t kernel, int64_t stride, int64_t pad) {
  return (in + 2 * pad - kernel) / stride + 1;
}

}  // namespace

OverlapPatchEmbedImpl::OverlapPatchEmbedImpl(int64_t in, int64_t out, int64_t kernel, int64_t stride)
    : in_(in), out_(out), kernel_(kernel), stride_(stride) {
  proj_ = register_module(
      "proj", torch::nn::Conv2d(torch::nn::Conv2dOptions(in, out, kernel).stride(stride).padding(kernel / 2)));
  norm_ = register_module("norm", torch::nn::LayerNorm(torch::nn::LayerNormOptions({out})));
}

torch::Tensor OverlapPatchEmbedImpl::forward(const torch::Tensor& x, int64_t* h, int64_t* w) {
  torch::Tensor y = proj_->forward(x);  // [B,out,H',W']
  *h = y.size(2);
  *w = y.size(3);
  return norm_->forward(y.flatten(2).transpose(1, 2));  // [B,H'W',out]
}

double OverlapPatchEmbedImpl::Flops(int64_t h_in, int64_t w_in) const {
  const int64_t pad = kernel_ / 2;
  return ConvFlops(in_, out_, kernel_, ConvOut(h_in, kernel_, stride_, pad), ConvOut(w_in, kernel_, stride_, pad));
}

EfficientAttentionImpl::EfficientAttentionImpl(int64_t dim, int64_t heads, int64_t sr_ratio)
    : dim_(dim), heads_(heads), sr_ratio_(sr_ratio) {
  q_ = register_module("q", MakeLinear(dim, dim));
  kv_ = register_module("kv", MakeLinear(dim, 2 * dim));
  proj_ = register_module("proj", MakeLinear(dim, dim));
  if (sr_ratio > 1) {
    sr_ = register_module("sr", torch::nn::Conv2d(torch::nn::Conv2dOptions(dim, dim, sr_ratio).stride(sr_ratio)));
    sr_norm_ = register_module("sr_norm", torch::nn::LayerNorm(torch::nn::LayerNormOptions({dim})));
  }
}

torch::Tensor EfficientAttentionImpl::forward(const torch::Tensor& x, int64_t h, int64_t w) {
  const int64_t b = x.size(0), n = x.size(1), c = x.size(2);
  const int64_t d = c / heads_;
  torch::Tensor q = q_->forward(x).view({b, n, heads_, d}).transpose(1, 2);  // [B,h,N,d]
  torch::Tensor source = x;
  if (sr_ratio_ > 1) {
    torch::Tensor grid = x.transpose(1, 2).reshape({b, c, h, w});
    source = sr_norm_->forward(sr_->forward(grid).flatten(2).transpose(1, 2));  // [B,Nr,C]
  }
  const int64_t nr = source.size(1);
  torch::Tensor kv = kv_->forward(source).view({b, nr, 2, heads_, d}).permute({2, 0, 3, 1, 4});  // [2,B,h,Nr,d]
  torch::Tensor k = kv[0], v = kv[1];
  torch::Tensor attn = torch::matmul(q, k.transpose(-2, -1)) * (1.0 / std::sqrt(static_cast<double>(d)));
  attn = attn.softmax(-1);                                                        // [B,h,N,Nr]
  torch::Tensor out = torch::matmul(attn, v).transpose(1, 2).reshape({b, n, c});  // [B,N,C]
  return proj_->forward(out);
}

double EfficientAttentionImpl::Flops(int64_t h, int64_t w) const {
  const double n = static_cast<double>(h) * w;
  double nr = n;
  double flops = 2.0 * n * dim_ * dim_;  // q
  if (sr_ratio_ > 1) {
    const int64_t hr = h / sr_ratio_, wr = w / sr_ratio_;
    nr = static_cast<double>(hr) * wr;
    flops += ConvFlops(dim_, dim_, sr_ratio_, hr, wr);
  }
  flops += 2.0 * nr * dim_ * 2 * dim_;  // kv
  flops += 2.0 * n * nr * dim_ * 2;     // scores + weighted sum
  flops += 2.0 * n * dim_ * dim_;       // proj
  return flops;
}

MixFfnImpl::MixFfnImpl(int64_t dim, int64_t hidden) : dim_(dim), hidden_(hidden) {
  fc1_ = register_module("fc1", MakeLinear(dim, hidden));
  dw_ = register_module("dwconv",
                        torch::nn::Conv2d(torch::nn::Conv2dOptions(hidden, hidden, 3).padding(1).groups(hidden)));
  fc2_ = register_module("fc2", MakeLinear(hidden, dim));
}

torch::Tensor MixFfnImpl::forward(const torch::Tensor& x, int64_t h, int64_t w) {
  const int64_t b = x.size(0), n = x.size(1);
  torch::Tensor y = fc1_->forward(x);                               // [B,N,hidden]
  y = dw_->forward(y.transpose(1, 2).reshape({b, hidden_, h, w}));  // [B,hidden,h,w]
  y = F::gelu(y.flatten(2).transpose(1, 2));                        // [B,N,hidden]
  (void)n;
  return fc2_->forward(y);
}

double MixFfnImpl::Flops(int64_t h, int64_t w) const {
  const double n = static_cast<double>(h) * w;
  return 2.0 * n * dim_ * hidden_ * 2 + ConvFlops(hidden_, hidden_, 3, h, w, hidden_);
}

MitBlockImpl::MitBlockImpl(int64_t dim, int64_t heads, int64_t sr_ratio, int64_t mlp_ratio) {
  norm1_ = register_module("norm1", torch::nn::LayerNorm(torch::nn::LayerNormOptions({dim})));
  attn_ = register_module("attn", EfficientAttention(dim, heads, sr_ratio));
  norm2_ = register_module("norm2", torch::nn::LayerNorm(torch::nn::LayerNormOptions({dim})));
  ffn_ = register_module("ffn", MixFfn(dim, dim * mlp_ratio));
}

torch::Tensor MitBlockImpl::forward(const torch::Tensor& x, int64_t h, int64_t w) {
  torch::Tensor y = x + attn_->forward(norm1_->forward(x), h, w);
  return y + ffn_->forward(norm2_->forward(y), h, w);
}

double MitBlockImpl::Flops(int64_t h, int64_t w) const { return attn_->Flops(h, w) + ffn_->Flops(h, w); }

SegFormerEncoderImpl::SegFormerEncoderImpl(const ModelConfig& config, int64_t in_channels)
    : decoder_dim_(config.decoder_dim) {
  config.Validate();
  int64_t in = in_channels;
  for (int s = 0; s < 4; ++s) {
    const int64_t width = config.encoder_widths[s];
    widths_.push_back(width);
    const std::string prefix = "stage" + std::to_string(s);
    embeds_.push_back(register_module(prefix + "_embed", OverlapPatchEmbed(in, width, s == 0 ? 7 : 3, s == 0 ? 4 : 2)));
    std::vector<MitBlock> stage;
    for (int i = 0; i < config.encoder_depths[s]; ++i) {
      stage.push_back(register_module(
          prefix + "_block" + std::to_string(i),
          MitBlock(width, config.encoder_heads[s], config.encoder_sr_ratios[s], config.encoder_mlp_ratio)));
    }
    blocks_.push_back(stage);
    norms_.push_back(register_module(prefix + "_norm", torch::nn::LayerNorm(torch::nn::LayerNormOptions({width}))));
    head_linears_.push_back(register_module("head_linear" + std::to_string(s), MakeLinear(width, decoder_dim_)));
    in = width;
  }
  fuse_ = register_module("head_fuse",
                          torch::nn::Conv2d(torch::nn::Conv2dOptions(4 * decoder_dim_, decoder_dim_, 1).bias(false)));
}

std::vector<torch::Tensor> SegFormerEncoderImpl::Stages(const torch::Tensor& x) {
  AVATAR_CHECK_INPUT(x.dim() == 4 && x.size(2) % 32 == 0 && x.size(3) % 32 == 0)
      << "SegFormer input must be [B,C,H,W] with H and W multiples of 32, got " << x.sizes();
  std::vector<torch::Tensor> outs;
  torch::Tensor y = x;
  for (size_t s = 0; s < 4; ++s) {
    int64_t h = 0, w = 0;
    torch::Tensor tokens = embeds_[s]->forward(y, &h, &w);  // [B,N,C_s]
    for (auto& block : blocks_[s]) tokens = block->forward(tokens, h, w);
    tokens = norms_[s]->forward(tokens);
    y = tokens.transpose(1, 2).reshape({x.size(0), widths_[s], h, w});  // [B,C_s,h,w]
    outs.push_back(y);
  }
  return outs;
}

torch::Tensor SegFormerEncoderImpl::forward(const torch::Tensor& x) {
  const std::vector<torch::Tensor> stages = Stages(x);
  const int64_t h = stages[0].size(2), w = stages[0].size(3);
  std::vector<torch::Tensor> upsampled(4);
  for (int s = 3; s >= 0; --s) {
    const auto& f = stages[s];
    torch::Tensor y = head_linears_[s]->forward(f.flatten(2).transpose(1, 2));  // [B,n,D]
    y = y.transpose(1, 2).reshape({f.size(0), decoder_dim_, f.size(2), f.size(3)});
    if (s > 0) {
      y = F::interpolate(
          y, F::InterpolateFuncOptions().size(std::vector<int64_t>{h, w}).mode(torch::kBilinear).align_corners(false));
    }
    upsampled[3 - s] = y;
  }
  return fuse_->forward(torch::cat(upsampled, 1));  // [B,D,H/4,W/4]
}

std::vector<FlopEntry> SegFormerEncoderImpl::Flops(int64_t size) const {
  std::vector<FlopEntry> entries;
  int64_t in_size = size;
  double head = 0.0;
  const int64_t quarter = size / 4;
  for (size_t s = 0; s < 4; ++s) {
    double flops = embeds_[s]->Flops(in_size, in_size);
    const int64_t side = size >> (s + 2);
    for (const auto& block : blocks_[s]) flops += block->Flops(side, side);
    entries.push_back({"stage" + std::to_string(s), flops});
    head += 2.0 * static_cast<double>(side) * side * widths_[s] * decoder_dim_;
    in_size = side;
  }
  head += ConvFlops(4 * decoder_dim_, decoder_dim_, 1, quarter, quarter);
  entries.push_back({"head", head});
  return entries;
}

}  // namespace avatar
