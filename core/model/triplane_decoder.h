#pragma once
// The tri-plane decoder of EG3D as used by GOHA: a two-layer MLP with equalised learning rate
// that maps the plane-averaged feature of a 3-D point to a raw density and C' colour features.
// It has no view-direction input.

#include <torch/torch.h>

namespace avatar {

// Sizes of the published decoder.
inline constexpr int64_t kDecoderInputChannels = 32;
inline constexpr int64_t kDecoderHiddenChannels = 64;
inline constexpr int64_t kDecoderFeatureChannels = 32;

// out[...,0] = raw density (the renderer applies softplus(raw - 1));
// out[...,1:] = sigmoid(x) * (1 + 2 * 0.001) - 0.001, i.e. features in [-0.001, 1.001].
class TriplaneDecoderImpl : public torch::nn::Module {
 public:
  // `in`, `hidden`, `features`: layer widths (32 -> 64 -> 1 + 32 in the paper).
  explicit TriplaneDecoderImpl(int64_t in = kDecoderInputChannels, int64_t hidden = kDecoderHiddenChannels,
                               int64_t features = kDecoderFeatureChannels);

  // features: [..., in] any float dtype -> [..., 1 + features], same dtype and device.
  // Differentiable when grad mode is on; in no-grad/inference mode it works in place.
  // Throws InvalidInput when the last dimension is not `in`.
  torch::Tensor forward(const torch::Tensor& features);

  // Sets the weights so that the layers compute exactly y = w x + b with the given effective
  // w1 [hidden,in], b1 [hidden], w2 [1+features,hidden], b2 [1+features] (undoing the
  // equalised-learning-rate gain). Used by tests and tools that need a hand-made field.
  // Throws InvalidInput on a shape mismatch.
  void SetEffectiveWeights(const torch::Tensor& w1, const torch::Tensor& b1, const torch::Tensor& w2,
                           const torch::Tensor& b2);

  int64_t in_channels() const { return in_; }
  int64_t feature_channels() const { return features_; }
  // FLOPs of one forward per point (multiply-add counted as 2), for benchmarks.
  double FlopsPerPoint() const { return 2.0 * static_cast<double>(in_ * hidden_ + hidden_ * (1 + features_)); }

  // Stored parameters: the effective weight is stored weight / sqrt(fan_in) (StyleGAN's
  // equalised learning rate with lr multiplier 1); biases are used as stored.
  torch::Tensor fc1_weight;  // [hidden, in], initialised N(0,1)
  torch::Tensor fc1_bias;    // [hidden], initialised 0
  torch::Tensor fc2_weight;  // [1 + features, hidden], initialised N(0,1)
  torch::Tensor fc2_bias;    // [1 + features], initialised 0

 private:
  int64_t in_;
  int64_t hidden_;
  int64_t features_;
};
TORCH_MODULE(TriplaneDecoder);

}  // namespace avatar
