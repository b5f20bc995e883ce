#include "core/model/triplane_decoder.h"

#include <cmath>

#include "core/util/error.h"

namespace avatar {

namespace {

// Keeps the features' sigmoid output a little beyond [0,1] so 0 and 1 are reachable (EG3D).
constexpr double kFeatureMargin = 0.001;

}  // namespace

TriplaneDecoderImpl::TriplaneDecoderImpl(int64_t in, int64_t hidden, int64_t features)
    : in_(in), hidden_(hidden), features_(features) {
  AVATAR_CHECK_INPUT(in > 0 && hidden > 0 && features >= 0)
      << "decoder widths must be positive, got " << in << ", " << hidden << ", " << features;
  fc1_weight = register_parameter("fc1_weight", torch::randn({hidden, in}));
  fc1_bias = register_parameter("fc1_bias", torch::zeros({hidden}));
  fc2_weight = register_parameter("fc2_weight", torch::randn({1 + features, hidden}));
  fc2_bias = register_parameter("fc2_bias", torch::zeros({1 + features}));
}

torch::Tensor TriplaneDecoderImpl::forward(const torch::Tensor& features) {
  AVATAR_CHECK_INPUT(features.dim() >= 1 && features.size(-1) == in_)
      << "decoder expects [..., " << in_ << "] features, got " << features.sizes();
  const auto lead = features.sizes().vec();
  const torch::Tensor x = features.reshape({-1, in_});
  const auto dtype = x.scalar_type();
  // Effective weights, transposed so both products are row-major [points, channels] GEMMs.
  const torch::Tensor w1 = (fc1_weight.to(dtype) * (1.0 / std::sqrt(static_cast<double>(in_)))).t();
  const torch::Tensor w2 = (fc2_weight.to(dtype) * (1.0 / std::sqrt(static_cast<double>(hidden_)))).t();
  torch::Tensor hidden = torch::addmm(fc1_bias.to(dtype), x, w1);
  torch::Tensor out;
  if (torch::GradMode::is_enabled()) {
    hidden = torch::softplus(hidden);
    out = torch::addmm(fc2_bias.to(dtype), hidden, w2);
    out = torch::cat({out.narrow(1, 0, 1),
                      torch::sigmoid(out.narrow(1, 1, features_)) * (1.0 + 2.0 * kFeatureMargin) - kFeatureMargin},
                     1);
  } else {
    // Same arithmetic without the temporaries: this is the hot path of inference rendering.
    torch::softplus_out(hidden, hidden, 1, 20);
    out = torch::addmm(fc2_bias.to(dtype), hidden, w2);
    torch::Tensor feat = out.narrow(1, 1, features_);
    feat.sigmoid_().mul_(1.0 + 2.0 * kFeatureMargin).sub_(kFeatureMargin);
  }
  auto out_shape = lead;
  out_shape.back() = 1 + features_;
  return out.view(out_shape);
}

void TriplaneDecoderImpl::SetEffectiveWeights(const torch::Tensor& w1, const torch::Tensor& b1, const torch::Tensor& w2,
                                              const torch::Tensor& b2) {
  AVATAR_CHECK_INPUT(w1.sizes() == fc1_weight.sizes() && b1.sizes() == fc1_bias.sizes() &&
                     w2.sizes() == fc2_weight.sizes() && b2.sizes() == fc2_bias.sizes())
      << "effective decoder weights have the wrong shapes: " << w1.sizes() << " " << b1.sizes() << " " << w2.sizes()
      << " " << b2.sizes();
  torch::NoGradGuard no_grad;
  const auto dtype = fc1_weight.scalar_type();
  fc1_weight.copy_(w1.to(fc1_weight.device(), dtype) * std::sqrt(static_cast<double>(in_)));
  fc1_bias.copy_(b1.to(fc1_bias.device(), dtype));
  fc2_weight.copy_(w2.to(fc2_weight.device(), dtype) * std::sqrt(static_cast<double>(hidden_)));
  fc2_bias.copy_(b2.to(fc2_bias.device(), dtype));
}

}  // namespace avatar
