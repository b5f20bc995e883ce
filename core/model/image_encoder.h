#pragma once
// The interface shared by the encoders GOHA can use for E_c, E_p and E_e (ModelConfig::encoder):
// an image [B,in_channels,S,S] (S a multiple of 32, normalised the way InputNormalisation says)
// becomes the feature map F [B,decoder_dim,S/4,S/4] that Embed2Plane and the appearance lifting
// take. Implementations: SegFormerEncoder (mit_b0) and MobileNetV2Encoder (mobilenet_v2).

#include <string>
#include <vector>

#include <torch/torch.h>

namespace avatar {

// One named cost entry for `inspect`.
struct FlopEntry {
  std::string module;  // e.g. "E_c/stage2"
  double flops = 0.0;  // analytic FLOPs of one forward, batch 1
};

// Analytic conv cost: 2 * in/groups * k^2 * out * h_out * w_out (defined in segformer.cc).
double ConvFlops(int64_t in, int64_t out, int64_t kernel, int64_t h_out, int64_t w_out, int64_t groups = 1);

class ImageEncoderImpl : public torch::nn::Module {
 public:
  ~ImageEncoderImpl() override = default;
  // x [B,in_channels,S,S] -> [B,decoder_dim,S/4,S/4]. Throws InvalidInput for a bad shape.
  virtual torch::Tensor forward(const torch::Tensor& x) = 0;
  // Named FLOPs of one forward for an S x S input, batch 1.
  virtual std::vector<FlopEntry> Flops(int64_t size) const = 0;
};
TORCH_MODULE(ImageEncoder);

}  // namespace avatar
