#include "core/render/depth_sampling.h"

#include "core/util/error.h"

namespace avatar::render {

namespace {

// Added to every smoothed weight so that empty rays still spread their importance samples.
constexpr double kWeightFloor = 0.01;
// Added to the PDF before normalising, and the smallest CDF step treated as non-empty.
constexpr double kPdfEpsilon = 1e-5;

}  // namespace

torch::Tensor StratifiedDepths(int64_t batch, int64_t rays, int64_t samples, double near, double far,
                               bool deterministic, const torch::TensorOptions& options,
                               c10::optional<at::Generator> generator) {
  AVATAR_CHECK_INPUT(samples >= 1 && batch >= 1 && rays >= 0) << "bad stratified sample counts";
  AVATAR_CHECK_INPUT(far > near) << "depth range must have far > near, got [" << near << ", " << far << "]";
  const double step = (far - near) / static_cast<double>(samples);
  const torch::Tensor starts = torch::arange(samples, options) * step + near;  // [S]
  if (deterministic) {
    return (starts + 0.5 * step).view({1, 1, samples}).expand({batch, rays, samples}).contiguous();
  }
  const torch::Tensor jitter = torch::rand({batch, rays, samples}, generator, options);
  return starts.view({1, 1, samples}) + jitter * step;
}

torch::Tensor ImportanceDepths(const torch::Tensor& coarse_depths, const torch::Tensor& coarse_weights, int64_t samples,
                               bool deterministic, c10::optional<at::Generator> generator) {
  AVATAR_CHECK_INPUT(coarse_depths.dim() == 3 && coarse_depths.size(2) >= 4)
      << "importance sampling needs coarse depths [B,N,S] with S >= 4, got " << coarse_depths.sizes();
  const int64_t b = coarse_depths.size(0), n = coarse_depths.size(1), s = coarse_depths.size(2);
  AVATAR_CHECK_INPUT(coarse_weights.dim() == 3 && coarse_weights.size(0) == b && coarse_weights.size(1) == n &&
                     coarse_weights.size(2) == s - 1)
      << "coarse weights must be [B,N,S-1] = [" << b << "," << n << "," << s - 1 << "], got " << coarse_weights.sizes();
  AVATAR_CHECK_INPUT(samples >= 1) << "importance samples must be >= 1";
  torch::NoGradGuard no_grad;
  const auto opts = coarse_depths.options();
  const int64_t rays = b * n;
  if (rays == 0) return torch::empty({b, n, samples}, opts);
  const torch::Tensor z = coarse_depths.reshape({rays, s});
  const torch::Tensor w = coarse_weights.detach().reshape({rays, 1, s - 1}).to(opts.dtype());
  // Smoothing: a 2-wide max filter (padded, S outputs) followed by a 2-wide mean (S-1 outputs).
  torch::Tensor smooth = torch::max_pool1d(w, 2, 1, 1);
  smooth = torch::avg_pool1d(smooth, 2, 1).squeeze(1) + kWeightFloor;                // [rays,S-1]
  const int64_t bins = s - 3;                                                        // intervals with a weight
  const torch::Tensor mids = 0.5 * (z.narrow(1, 0, s - 1) + z.narrow(1, 1, s - 1));  // [rays,S-1] edges
  const torch::Tensor pdf_w = smooth.narrow(1, 1, bins) + kPdfEpsilon;
  const torch::Tensor pdf = pdf_w / pdf_w.sum(1, true);
  const torch::Tensor cdf = torch::cat({torch::zeros({rays, 1}, opts), torch::cumsum(pdf, 1)}, 1);  // [rays,bins+1]
  torch::Tensor u;
  if (deterministic) {
    u = ((torch::arange(samples, opts) + 0.5) / static_cast<double>(samples))
            .view({1, samples})
            .expand({rays, samples});
  } else {
    // Sorted quantiles give sorted depths (the inverse CDF is monotone).
    u = std::get<0>(torch::sort(torch::rand({rays, samples}, generator, opts), 1));
  }
  u = u.contiguous();
  const torch::Tensor above_raw = torch::searchsorted(cdf, u, /*out_int32=*/false, /*right=*/true);
  const torch::Tensor below = torch::clamp_min(above_raw - 1, 0);
  const torch::Tensor above = torch::clamp_max(above_raw, bins);
  const torch::Tensor cdf_lo = cdf.gather(1, below), cdf_hi = cdf.gather(1, above);
  const torch::Tensor bin_lo = mids.gather(1, below), bin_hi = mids.gather(1, above);
  torch::Tensor denom = cdf_hi - cdf_lo;
  denom = torch::where(denom < kPdfEpsilon, torch::ones_like(denom), denom);
  const torch::Tensor t = (u - cdf_lo) / denom;
  return (bin_lo + t * (bin_hi - bin_lo)).view({b, n, samples});
}

}  // namespace avatar::render
