#include "core/train/metrics.h"

#include <cmath>
#include <limits>

#include "core/train/losses.h"
#include "core/util/error.h"

namespace avatar::train {

namespace F = torch::nn::functional;

namespace {

void CheckPair(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask, const char* what) {
  AVATAR_CHECK_INPUT(a.dim() == 4 && a.sizes() == b.sizes())
      << what << ": images must be two [B,C,H,W] tensors of one shape, got " << a.sizes() << " and " << b.sizes();
  if (mask.defined()) {
    AVATAR_CHECK_INPUT(mask.dim() == 4 && mask.size(0) == a.size(0) && mask.size(1) == 1 && mask.size(2) == a.size(2) &&
                       mask.size(3) == a.size(3))
        << what << ": mask must be [B,1,H,W] matching the images, got " << mask.sizes();
  }
}

// Normalised 1-D Gaussian taps.
torch::Tensor Gaussian(int size, double sigma, const torch::TensorOptions& options) {
  torch::Tensor x = torch::arange(size, options.dtype(torch::kFloat64)) - (size - 1) / 2.0;
  torch::Tensor g = torch::exp(-(x * x) / (2.0 * sigma * sigma));
  return (g / g.sum()).to(options.dtype());
}

// Separable valid Gaussian filter of every channel: [B,C,H,W] -> [B,C,H-10,W-10].
torch::Tensor Blur(const torch::Tensor& x, const torch::Tensor& taps) {
  const int64_t c = x.size(1), k = taps.size(0);
  const torch::Tensor row = taps.view({1, 1, 1, k}).expand({c, 1, 1, k}).contiguous();
  const torch::Tensor col = taps.view({1, 1, k, 1}).expand({c, 1, k, 1}).contiguous();
  torch::Tensor y = F::conv2d(x, row, F::Conv2dFuncOptions().groups(c));
  return F::conv2d(y, col, F::Conv2dFuncOptions().groups(c));
}

}  // namespace

torch::Tensor PsnrPerImage(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask) {
  CheckPair(a, b, mask, "PSNR");
  const torch::Tensor sq = (a - b).pow(2);
  torch::Tensor mse;
  if (mask.defined()) {
    const torch::Tensor w = mask.expand_as(sq);
    mse = (sq * w).sum({1, 2, 3}) / w.sum({1, 2, 3}).clamp_min(1e-12);
  } else {
    mse = sq.mean({1, 2, 3});
  }
  // Peak-to-peak range of [-1,1] is 2: PSNR = 10 log10(4 / MSE).
  return 10.0 * torch::log10(4.0 / mse);
}

torch::Tensor SsimPerImage(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask) {
  CheckPair(a, b, mask, "SSIM");
  constexpr int kWindow = 11;
  AVATAR_CHECK_INPUT(a.size(2) >= kWindow && a.size(3) >= kWindow)
      << "SSIM needs images of at least 11x11 pixels, got " << a.size(2) << "x" << a.size(3);
  const torch::Tensor x = (a + 1.0) * 0.5, y = (b + 1.0) * 0.5;
  const torch::Tensor taps = Gaussian(kWindow, 1.5, x.options());
  const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
  const torch::Tensor mx = Blur(x, taps), my = Blur(y, taps);
  const torch::Tensor vx = Blur(x * x, taps) - mx * mx;
  const torch::Tensor vy = Blur(y * y, taps) - my * my;
  const torch::Tensor cxy = Blur(x * y, taps) - mx * my;
  const torch::Tensor map = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
  if (!mask.defined()) return map.mean({1, 2, 3});
  const int64_t r = kWindow / 2;
  const torch::Tensor centre =
      mask.narrow(2, r, map.size(2)).narrow(3, r, map.size(3)).expand_as(map);
  return (map * centre).sum({1, 2, 3}) / centre.sum({1, 2, 3}).clamp_min(1e-12);
}

ImageMetrics ComputeImageMetrics(
    const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask,
    const std::function<torch::Tensor(const torch::Tensor&, const torch::Tensor&, const torch::Tensor&)>& perceptual) {
  torch::NoGradGuard no_grad;
  ImageMetrics m;
  m.psnr = PsnrPerImage(a, b, mask);
  m.ssim = SsimPerImage(a, b, mask);
  m.l1 = L1Distance(a, b, mask);
  if (perceptual) m.perceptual = perceptual(a, b, mask);
  return m;
}

}  // namespace avatar::train
