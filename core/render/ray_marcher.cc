#include "core/render/ray_marcher.h"

#include "core/util/error.h"

namespace avatar::render {

MarchWeights ComputeMarchWeights(const torch::Tensor& raw_density, const torch::Tensor& depths, double far,
                                 bool with_depth) {
  AVATAR_CHECK_INPUT(raw_density.dim() == 3 && depths.sizes() == raw_density.sizes() && raw_density.size(2) >= 2)
      << "ray marching needs raw density and depths [B,N,S] with S >= 2, got " << raw_density.sizes() << " and "
      << depths.sizes();
  const int64_t s = raw_density.size(2);
  const torch::Tensor t0 = depths.narrow(2, 0, s - 1), t1 = depths.narrow(2, 1, s - 1);
  const torch::Tensor delta = t1 - t0;
  const torch::Tensor raw_mid = 0.5 * (raw_density.narrow(2, 0, s - 1) + raw_density.narrow(2, 1, s - 1));
  // The cap only matters for an infinite raw density (inf * a zero-length interval = NaN); any
  // finite density above it is opaque within 1e-30 world units anyway.
  const torch::Tensor sigma = torch::softplus(raw_mid - 1.0).clamp_max(kMaxDensity);
  const torch::Tensor tau = sigma * delta;          // [B,N,S-1] >= 0
  const torch::Tensor cum = torch::cumsum(tau, 2);  // inclusive
  const torch::Tensor before = torch::cat({torch::zeros_like(cum.narrow(2, 0, 1)), cum.narrow(2, 0, s - 2)}, 2);
  const torch::Tensor alpha = -torch::expm1(-tau);
  MarchWeights out;
  out.interval_weights = torch::exp(-before) * alpha;
  const torch::Tensor zero = torch::zeros_like(out.interval_weights.narrow(2, 0, 1));
  out.sample_weights =
      0.5 * (torch::cat({zero, out.interval_weights}, 2) + torch::cat({out.interval_weights, zero}, 2));
  out.midpoints = 0.5 * (t0 + t1);
  out.opacity = -torch::expm1(-cum.select(2, s - 2));
  if (!with_depth) return out;
  const torch::Tensor wsum = out.interval_weights.sum(2);
  out.depth =
      ((out.interval_weights * out.midpoints).sum(2) + kEmptyRayDepthWeight * far) / (wsum + kEmptyRayDepthWeight);
  return out;
}

torch::Tensor CompositeFeatures(const torch::Tensor& sample_weights, const torch::Tensor& features) {
  AVATAR_CHECK_INPUT(sample_weights.dim() == 3 && features.dim() == 4 &&
                     features.sizes().slice(0, 3) == sample_weights.sizes())
      << "composite needs weights [B,N,S] and features [B,N,S,C], got " << sample_weights.sizes() << " and "
      << features.sizes();
  const int64_t b = features.size(0), n = features.size(1), s = features.size(2), c = features.size(3);
  // One [1,S] x [S,C] product per ray: reads each feature once, no [B,N,S,C] temporary.
  return torch::bmm(sample_weights.reshape({b * n, 1, s}), features.reshape({b * n, s, c})).view({b, n, c});
}

MarchResult MarchRays(const torch::Tensor& raw_density, const torch::Tensor& features, const torch::Tensor& depths,
                      double far) {
  MarchResult result;
  result.weights = ComputeMarchWeights(raw_density, depths, far);
  result.features = CompositeFeatures(result.weights.sample_weights, features) * 2.0 - 1.0;
  return result;
}

}  // namespace avatar::render
