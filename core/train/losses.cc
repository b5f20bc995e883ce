#include "core/train/losses.h"

#include <cmath>

#include "core/model/super_resolution.h"
#include "core/util/error.h"

namespace avatar::train {

namespace {
void CheckImages(const torch::Tensor& a, const torch::Tensor& b, const char* what) {
  AVATAR_CHECK_INPUT(a.defined() && b.defined() && a.dim() == 4 && a.sizes() == b.sizes())
      << what << ": wants two image batches [B,C,H,W] of one shape, got " << (a.defined() ? a.sizes() : c10::IntArrayRef{})
      << " and " << (b.defined() ? b.sizes() : c10::IntArrayRef{});
}
}  // namespace

torch::Tensor L1Distance(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask) {
  CheckImages(a, b, "L1Distance");
  const torch::Tensor diff = (a - b).abs();
  if (!mask.defined()) return diff.mean({1, 2, 3});
  AVATAR_CHECK_INPUT(mask.dim() == 4 && mask.size(0) == a.size(0) && mask.size(1) == 1 && mask.size(2) == a.size(2) &&
                     mask.size(3) == a.size(3))
      << "L1Distance: mask must be [B,1,H,W] matching the images, got " << mask.sizes();
  const torch::Tensor m = mask.to(a.scalar_type());
  return (diff * m).sum({1, 2, 3}) / (m.sum({1, 2, 3}) * a.size(1) + 1e-8);
}

torch::Tensor PyramidL1Distance(const torch::Tensor& a, const torch::Tensor& b, int levels) {
  CheckImages(a, b, "PyramidL1Distance");
  AVATAR_CHECK_INPUT(levels >= 1) << "PyramidL1Distance: levels must be >= 1";
  torch::Tensor x = a, y = b;
  torch::Tensor sum = L1Distance(x, y);
  int used = 1;
  for (int l = 1; l < levels && x.size(2) >= 2 && x.size(3) >= 2; ++l, ++used) {
    x = torch::avg_pool2d(x, 2);
    y = torch::avg_pool2d(y, 2);
    sum = sum + L1Distance(x, y);
  }
  return sum / used;
}

torch::Tensor ImageLoss(const torch::Tensor& a, const torch::Tensor& b, const PerceptualFn& perceptual,
                        double perceptual_weight) {
  torch::Tensor loss = L1Distance(a, b);
  if (perceptual && perceptual_weight != 0.0) loss = loss + perceptual_weight * perceptual(a, b);
  return loss;
}

torch::Tensor Matte(const torch::Tensor& image, const torch::Tensor& mask) {
  const torch::Tensor m = mask.to(image.scalar_type());
  return image * m + (m - 1.0);
}

torch::Tensor ResizeTo(const torch::Tensor& x, int64_t size) {
  AVATAR_CHECK_INPUT(x.defined() && x.dim() == 4 && size >= 1) << "ResizeTo: wants [B,C,H,W] and size >= 1";
  if (x.size(2) == size && x.size(3) == size) return x;
  if (x.size(2) >= size && x.size(3) >= size && x.size(2) % size == 0 && x.size(3) % size == 0)
    return torch::adaptive_avg_pool2d(x, {size, size});
  return ResizeBilinear(x, size, size);
}

torch::Tensor NeutralLoss(const torch::Tensor& canonical_rgb, const torch::Tensor& neutral_image,
                          const torch::Tensor& neutral_mask, const PerceptualFn& perceptual,
                          double perceptual_weight) {
  AVATAR_CHECK_INPUT(canonical_rgb.defined() && canonical_rgb.dim() == 4 && canonical_rgb.size(2) == canonical_rgb.size(3))
      << "NeutralLoss: canonical render must be square [B,3,R,R]";
  const int64_t r = canonical_rgb.size(2);
  const torch::Tensor neu = ResizeTo(neutral_image.to(canonical_rgb.scalar_type()), r);
  const torch::Tensor mask = ResizeTo(neutral_mask.to(canonical_rgb.scalar_type()), r);
  AVATAR_CHECK_INPUT(neu.sizes() == canonical_rgb.sizes() && mask.size(1) == 1)
      << "NeutralLoss: I_neu " << neutral_image.sizes() << " / M_neu " << neutral_mask.sizes()
      << " do not match the render " << canonical_rgb.sizes();
  return ImageLoss(Matte(canonical_rgb, mask), Matte(neu, mask), perceptual, perceptual_weight);
}

torch::Tensor DensityTvAt(const DensityFn& density, const torch::Tensor& points, const torch::Tensor& perturbed) {
  AVATAR_CHECK_INPUT(points.defined() && points.dim() == 3 && points.size(2) == 3 && perturbed.sizes() == points.sizes())
      << "DensityTvAt: wants points and perturbed points [B,P,3] of one shape";
  const int64_t p = points.size(1);
  // One field call for both sets (the tri-plane field costs one plane lookup per call).
  const torch::Tensor sigma = density(torch::cat({points, perturbed}, 1));
  AVATAR_CHECK_INPUT(sigma.dim() == 2 && sigma.size(1) == 2 * p) << "DensityTvAt: density must return [B,P]";
  return (sigma.narrow(1, 0, p) - sigma.narrow(1, p, p)).abs().mean();
}

torch::Tensor DensityTvLoss(const DensityFn& density, int64_t batch, const TvOptions& options,
                            const torch::TensorOptions& tensor_options) {
  AVATAR_CHECK_INPUT(batch >= 1 && options.num_points >= 1 && options.sigma >= 0 && options.box_warp > 0)
      << "DensityTvLoss: batch and num_points must be >= 1, sigma >= 0, box_warp > 0";
  const double half = options.box_warp / 2.0;
  const torch::Tensor points = (torch::rand({batch, options.num_points, 3}, tensor_options) * 2.0 - 1.0) * half;
  const torch::Tensor perturbed = points + torch::randn_like(points) * (options.sigma * half);
  return DensityTvAt(density, points, perturbed);
}

double Psnr(const torch::Tensor& a, const torch::Tensor& b) {
  const double mse = ((a.detach().to(torch::kFloat64) - b.detach().to(torch::kFloat64)) / 2.0).pow(2).mean().item<double>();
  return 10.0 * std::log10(1.0 / std::max(mse, 1e-20));
}

}  // namespace avatar::train
