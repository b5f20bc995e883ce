#pragma once
// Sample depths along rays: stratified coarse samples and importance samples drawn from the
// coarse weights with the published scheme (EG3D/GOHA). Depths carry no gradient.
//
// Two modes. Random (training): jitter inside each stratum and uniform random CDF
// quantiles. Deterministic (inference default): stratum centres and the fixed quantiles
// (k + 0.5) / M, so a still camera renders bit-identical frames.

#include <torch/torch.h>

namespace avatar::render {

// Depths [B,N,S] in [near, far]: stratum k covers near + [k, k+1] * (far - near) / S; the
// sample is its centre (deterministic) or uniform inside it (random). Sorted per ray.
// `generator` (optional) drives the random mode.
torch::Tensor StratifiedDepths(int64_t batch, int64_t rays, int64_t samples, double near, double far,
                               bool deterministic, const torch::TensorOptions& options,
                               c10::optional<at::Generator> generator = c10::nullopt);

// Importance depths [B,N,M], sorted per ray, from coarse depths [B,N,S] (sorted, S >= 4) and
// the coarse marcher's interval weights [B,N,S-1]. The weights are smoothed (max-pool k2 s1
// p1, then average-pool k2 s1, then + 0.01); the bins are the midpoints of the coarse depths
// and bin k (between midpoints k and k+1, k < S-3) gets the smoothed weight k+1, + 1e-5;
// samples are drawn by inverse CDF at the quantiles described above.
torch::Tensor ImportanceDepths(const torch::Tensor& coarse_depths, const torch::Tensor& coarse_weights, int64_t samples,
                               bool deterministic, c10::optional<at::Generator> generator = c10::nullopt);

}  // namespace avatar::render
