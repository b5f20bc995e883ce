#include "core/render/rays.h"

#include "core/util/error.h"

namespace avatar::render {

namespace {

// Rays through the normalised image points (u, v) [1,N] or [B,N] of each camera.
Rays RaysThrough(const Cameras& cameras, const torch::Tensor& u, const torch::Tensor& v, int64_t n) {
  const int64_t b = cameras.batch();
  const auto& k = cameras.intrinsics;
  const auto kk = [&](int r, int c) { return k.select(1, r).select(1, c).unsqueeze(1); };  // [B,1]
  const torch::Tensor fx = kk(0, 0), skew = kk(0, 1), cx = kk(0, 2), fy = kk(1, 1), cy = kk(1, 2);
  // Inverse of the projection in camera.h (skew included).
  const torch::Tensor yc = (v - cy) / fy;                                          // [B,N]
  const torch::Tensor xc = (u - cx - skew * yc) / fx;                              // [B,N]
  const torch::Tensor cam_dirs = torch::stack({xc, yc, torch::ones_like(xc)}, 2);  // [B,N,3]
  const torch::Tensor rot = cameras.cam2world.narrow(1, 0, 3).narrow(2, 0, 3);     // [B,3,3]
  torch::Tensor dirs = torch::bmm(cam_dirs, rot.transpose(1, 2));                  // R d per ray
  dirs = dirs / dirs.norm(2, -1, true);
  Rays rays;
  rays.directions = dirs;
  rays.origins = cameras.cam2world.narrow(1, 0, 3).select(2, 3).unsqueeze(1).expand({b, n, 3});
  return rays;
}

// Normalised coordinates of the pixel centres 0..R-1 of one image axis, [R].
torch::Tensor PixelCentres(int64_t resolution, const torch::TensorOptions& opts) {
  return (torch::arange(resolution, opts) + 0.5) / static_cast<double>(resolution);
}

}  // namespace

Rays GenerateRays(const Cameras& cameras, int64_t resolution) {
  CheckCameras(cameras);
  AVATAR_CHECK_INPUT(resolution >= 1) << "ray resolution must be >= 1, got " << resolution;
  const torch::Tensor centres = PixelCentres(resolution, cameras.cam2world.options());
  // Row-major pixel order: v follows the row, u the column.
  const torch::Tensor v = centres.view({resolution, 1}).expand({resolution, resolution}).reshape({1, -1});
  const torch::Tensor u = centres.view({1, resolution}).expand({resolution, resolution}).reshape({1, -1});
  return RaysThrough(cameras, u, v, resolution * resolution);
}

Rays GenerateWindowRays(const Cameras& cameras, int64_t resolution, const torch::Tensor& corners, int64_t size) {
  CheckCameras(cameras);
  AVATAR_CHECK_INPUT(resolution >= 1) << "ray resolution must be >= 1, got " << resolution;
  AVATAR_CHECK_INPUT(size >= 1 && size <= resolution)
      << "a pixel window must be 1.." << resolution << " pixels wide, got " << size;
  const int64_t b = cameras.batch();
  AVATAR_CHECK_INPUT(corners.defined() && corners.dim() == 2 && corners.size(0) == b && corners.size(1) == 2 &&
                     !corners.is_floating_point() && !corners.is_complex())
      << "pixel window corners must be integers [" << b << ",2], got "
      << (corners.defined() ? corners.sizes() : c10::IntArrayRef{});
  // Checked where the corners are (a CPU tensor needs no device synchronisation).
  AVATAR_CHECK_INPUT(b == 0 ||
                     (corners.min().item<int64_t>() >= 0 && corners.max().item<int64_t>() <= resolution - size))
      << "a " << size << "x" << size << " pixel window must lie inside the " << resolution << "x" << resolution
      << " image (corners 0.." << resolution - size << ")";
  const auto opts = cameras.cam2world.options();
  const torch::Tensor at = corners.to(opts.device(), torch::kLong);
  const torch::Tensor centres = PixelCentres(resolution, opts);
  const torch::Tensor offsets = torch::arange(size, at.options());
  const torch::Tensor rows = at.select(1, 0).unsqueeze(1) + offsets;  // [B,size]
  const torch::Tensor cols = at.select(1, 1).unsqueeze(1) + offsets;  // [B,size]
  // The full image's centre values picked per pixel: the same numbers as GenerateRays uses.
  const torch::Tensor v =
      centres.index_select(0, rows.reshape({-1})).view({b, size, 1}).expand({b, size, size}).reshape({b, -1});
  const torch::Tensor u =
      centres.index_select(0, cols.reshape({-1})).view({b, 1, size}).expand({b, size, size}).reshape({b, -1});
  return RaysThrough(cameras, u, v, size * size);
}

}  // namespace avatar::render
