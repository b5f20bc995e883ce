#include "core/render/triplane_sampling.h"

#include <ATen/Parallel.h>

#include <cmath>
#include <type_traits>

#include "core/util/error.h"

namespace avatar::render {

namespace {

void CheckInputs(const torch::Tensor& planes, const torch::Tensor& points, double box_warp) {
  AVATAR_CHECK_INPUT(planes.defined() && planes.dim() == 5 && planes.size(1) == 3)
      << "tri-planes must be [B,3,C,H,W], got " << (planes.defined() ? planes.sizes() : c10::IntArrayRef{});
  AVATAR_CHECK_INPUT(points.defined() && points.dim() == 3 && points.size(2) == 3 && points.size(0) == planes.size(0))
      << "points must be [B,P,3] with B = " << planes.size(0) << ", got " << points.sizes();
  AVATAR_CHECK_INPUT(torch::isFloatingType(planes.scalar_type()) && planes.scalar_type() == points.scalar_type())
      << "planes and points must share one floating dtype";
  AVATAR_CHECK_INPUT(box_warp > 0.0 && std::isfinite(box_warp)) << "box_warp must be > 0, got " << box_warp;
}

// Samples points [begin, end) of the flattened [B*P] range. Inlined into the per-ISA clones below.
template <typename T>
inline __attribute__((always_inline)) void SampleRange(const T* planes, int64_t h, int64_t w, int64_t c,
                                                       const T* points, int64_t p, T scale, T* out, int64_t begin,
                                                       int64_t end) {
  const int64_t plane_stride = h * w * c;
  const T third = T(1) / T(3);
  for (int64_t idx = begin; idx < end; ++idx) {
    const int64_t b = idx / p;
    const T* q = points + idx * 3;
    T* o = out + idx * c;
    for (int64_t k = 0; k < c; ++k) o[k] = T(0);
    for (int plane = 0; plane < 3; ++plane) {
      // Unnormalise with align_corners = false: grid -1 is the left edge of texel 0.
      const T gx = q[kPlaneAxes[plane][0]] * scale, gy = q[kPlaneAxes[plane][1]] * scale;
      const T x = ((gx + T(1)) * static_cast<T>(w) - T(1)) * T(0.5);
      const T y = ((gy + T(1)) * static_cast<T>(h) - T(1)) * T(0.5);
      // Outside (-1, size) no corner is inside: zero padding. Also rejects NaN.
      if (!(x > T(-1) && x < static_cast<T>(w) && y > T(-1) && y < static_cast<T>(h))) continue;
      const T fx0 = std::floor(x), fy0 = std::floor(y);
      const int64_t x0 = static_cast<int64_t>(fx0), y0 = static_cast<int64_t>(fy0);
      const T ax = x - fx0, ay = y - fy0;
      const T wts[4] = {(T(1) - ax) * (T(1) - ay) * third, ax * (T(1) - ay) * third, (T(1) - ax) * ay * third,
                        ax * ay * third};
      const int64_t xs[4] = {x0, x0 + 1, x0, x0 + 1};
      const int64_t ys[4] = {y0, y0, y0 + 1, y0 + 1};
      const T* base = planes + (b * 3 + plane) * plane_stride;
      for (int corner = 0; corner < 4; ++corner) {
        if (xs[corner] < 0 || xs[corner] >= w || ys[corner] < 0 || ys[corner] >= h) continue;
        const T* src = base + (ys[corner] * w + xs[corner]) * c;
        const T wt = wts[corner];
        for (int64_t k = 0; k < c; ++k) o[k] += wt * src[k];
      }
    }
  }
}

// The channel loops vectorise; the build targets baseline x86-64, so GCC also emits an AVX2+FMA
// clone chosen at load time on CPUs that have it (same results up to FMA rounding). Not under
// ThreadSanitizer: GCC instruments the clones' resolver, which the loader runs before TSan's
// runtime exists, and every executable that links this file crashed at start.
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define AVATAR_SIMD_CLONES __attribute__((target_clones("arch=haswell", "default")))
#else
#define AVATAR_SIMD_CLONES
#endif

AVATAR_SIMD_CLONES void SampleRangeFloat(const float* planes, int64_t h, int64_t w, int64_t c, const float* points,
                                         int64_t p, float scale, float* out, int64_t begin, int64_t end) {
  SampleRange<float>(planes, h, w, c, points, p, scale, out, begin, end);
}

AVATAR_SIMD_CLONES void SampleRangeDouble(const double* planes, int64_t h, int64_t w, int64_t c, const double* points,
                                          int64_t p, double scale, double* out, int64_t begin, int64_t end) {
  SampleRange<double>(planes, h, w, c, points, p, scale, out, begin, end);
}

template <typename T>
void SampleKernel(const T* planes, int64_t batch, int64_t h, int64_t w, int64_t c, const T* points, int64_t p, T scale,
                  T* out) {
  at::parallel_for(0, batch * p, 1024, [&](int64_t begin, int64_t end) {
    if constexpr (std::is_same<T, float>::value) {
      SampleRangeFloat(planes, h, w, c, points, p, scale, out, begin, end);
    } else {
      SampleRangeDouble(planes, h, w, c, points, p, scale, out, begin, end);
    }
  });
}

}  // namespace

torch::Tensor PlanesChannelsLast(const torch::Tensor& planes) {
  AVATAR_CHECK_INPUT(planes.defined() && planes.dim() == 5 && planes.size(1) == 3) << "tri-planes must be [B,3,C,H,W]";
  return planes.permute({0, 1, 3, 4, 2}).contiguous();
}

torch::Tensor SampleTriplanesReference(const torch::Tensor& planes, const torch::Tensor& points, double box_warp) {
  CheckInputs(planes, points, box_warp);
  const int64_t b = planes.size(0), c = planes.size(2), h = planes.size(3), w = planes.size(4);
  const int64_t p = points.size(1);
  const torch::Tensor q = points * (2.0 / box_warp);
  const torch::Tensor index = torch::tensor(
      {kPlaneAxes[0][0], kPlaneAxes[0][1], kPlaneAxes[1][0], kPlaneAxes[1][1], kPlaneAxes[2][0], kPlaneAxes[2][1]},
      torch::TensorOptions().dtype(torch::kLong).device(points.device()));
  // [B,P,6] -> [B,P,3,2] -> [B,3,P,2] -> [B*3,1,P,2]
  const torch::Tensor grid =
      q.index_select(2, index).view({b, p, 3, 2}).permute({0, 2, 1, 3}).reshape({b * 3, 1, p, 2});
  const torch::Tensor sampled = torch::grid_sampler(planes.reshape({b * 3, c, h, w}), grid, /*bilinear*/ 0,
                                                    /*zeros*/ 0, /*align_corners=*/false);  // [B*3,C,1,P]
  return sampled.view({b, 3, c, p}).mean(1).transpose(1, 2);
}

torch::Tensor SampleTriplanesFast(const torch::Tensor& planes_channels_last, const torch::Tensor& points,
                                  double box_warp) {
  const auto& pl = planes_channels_last;
  AVATAR_CHECK_INPUT(pl.defined() && pl.dim() == 5 && pl.size(1) == 3 && pl.is_contiguous())
      << "fast tri-plane sampling needs contiguous channels-last planes [B,3,H,W,C]";
  AVATAR_CHECK_INPUT(points.dim() == 3 && points.size(2) == 3 && points.size(0) == pl.size(0))
      << "points must be [B,P,3] with B = " << pl.size(0) << ", got " << points.sizes();
  AVATAR_CHECK_INPUT(pl.device().is_cpu() && points.device().is_cpu() && pl.scalar_type() == points.scalar_type() &&
                     (pl.scalar_type() == torch::kFloat32 || pl.scalar_type() == torch::kFloat64))
      << "fast tri-plane sampling runs on CPU float32/float64 tensors of one dtype";
  AVATAR_CHECK_INPUT(box_warp > 0.0 && std::isfinite(box_warp)) << "box_warp must be > 0, got " << box_warp;
  const int64_t b = pl.size(0), h = pl.size(2), w = pl.size(3), c = pl.size(4), p = points.size(1);
  const torch::Tensor pts = points.contiguous();
  torch::Tensor out = torch::empty({b, p, c}, pl.options());
  AT_DISPATCH_FLOATING_TYPES(pl.scalar_type(), "SampleTriplanesFast", [&] {
    SampleKernel<scalar_t>(pl.data_ptr<scalar_t>(), b, h, w, c, pts.data_ptr<scalar_t>(), p,
                           static_cast<scalar_t>(2.0 / box_warp), out.data_ptr<scalar_t>());
  });
  return out;
}

torch::Tensor SampleTriplanes(const torch::Tensor& planes, const torch::Tensor& points, double box_warp) {
  CheckInputs(planes, points, box_warp);
  const bool needs_grad = torch::GradMode::is_enabled() && (planes.requires_grad() || points.requires_grad());
  const bool fast_ok = planes.device().is_cpu() && points.device().is_cpu() &&
                       (planes.scalar_type() == torch::kFloat32 || planes.scalar_type() == torch::kFloat64);
  if (needs_grad || !fast_ok) return SampleTriplanesReference(planes, points, box_warp);
  return SampleTriplanesFast(PlanesChannelsLast(planes), points, box_warp);
}

}  // namespace avatar::render
