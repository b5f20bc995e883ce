#pragma once
// Volume rendering quadrature over sorted samples (EG3D's "MipRayMarcher2" scheme).
//
// For S sorted samples there are S-1 intervals i = [t_i, t_{i+1}] with length delta_i,
// midpoint m_i, raw density (r_i + r_{i+1}) / 2 and feature (c_i + c_{i+1}) / 2:
//   sigma_i = min(softplus(raw_i - 1), kMaxDensity),   tau_i = sigma_i * delta_i  (optical depth)
//   T_i     = exp(-sum_{j<i} tau_j)  (transmittance, from an exclusive cumulative sum)
//   alpha_i = 1 - exp(-tau_i)        (computed as -expm1(-tau_i))
//   w_i     = T_i * alpha_i
// Working on optical depths in log space instead of the release's cumprod(1 - alpha + 1e-10)
// keeps every term in [0,1], has no bias term, stays exact for tiny densities (expm1) and
// gives finite gradients when an interval is fully opaque (cumprod's backward divides by
// 1 - alpha). opacity = 1 - exp(-sum tau) (= sum w exactly in real arithmetic).
// Feature composite = sum_i w_i (c_i + c_{i+1}) / 2 = sum_s v_s c_s with per-sample weights
// v_s = (w_{s-1} + w_s) / 2 (missing neighbours count 0). The black background adds nothing.
// Depth = (sum w_i m_i + e * far) / (sum w_i + e) with e = kEmptyRayDepthWeight: the
// weighted mean depth for any ray with visible density, the far plane for an empty ray,
// continuous in between; no NaN and no global clamp.

#include <torch/torch.h>

namespace avatar::render {

// Upper bound on sigma (see ray_marcher.cc).
inline constexpr double kMaxDensity = 1e30;
// Weight of the far-plane fallback in the depth average (see above).
inline constexpr double kEmptyRayDepthWeight = 1e-6;

struct MarchWeights {
  torch::Tensor interval_weights;  // [B,N,S-1] w_i in [0,1]
  torch::Tensor sample_weights;    // [B,N,S]   v_s in [0,1]
  torch::Tensor midpoints;         // [B,N,S-1] m_i
  torch::Tensor opacity;           // [B,N]     in [0,1]
  torch::Tensor depth;             // [B,N]     in [t_0, far] (see above)
};

// raw_density [B,N,S] (decoder output, before softplus), depths [B,N,S] sorted ascending;
// `far` is the empty-ray depth. Differentiable in raw_density. Throws InvalidInput for
// mismatched shapes or S < 2. with_depth = false leaves `depth` undefined (saves its sums).
MarchWeights ComputeMarchWeights(const torch::Tensor& raw_density, const torch::Tensor& depths, double far,
                                 bool with_depth = true);

// sum_s v_s * c_s: sample_weights [B,N,S], features [B,N,S,C] -> [B,N,C] (before the [-1,1]
// mapping). Differentiable in both.
torch::Tensor CompositeFeatures(const torch::Tensor& sample_weights, const torch::Tensor& features);

struct MarchResult {
  torch::Tensor features;  // [B,N,C] composite over black, mapped to [-1,1] (x * 2 - 1)
  MarchWeights weights;
};

// Convenience: weights + composite + mapping for samples already in one sorted set.
// raw_density [B,N,S], features [B,N,S,C], depths [B,N,S].
MarchResult MarchRays(const torch::Tensor& raw_density, const torch::Tensor& features, const torch::Tensor& depths,
                      double far);

}  // namespace avatar::render
