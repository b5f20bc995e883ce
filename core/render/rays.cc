#include "core/render/rays.h"

#include "core/util/error.h"

namespace avatar::render {

Rays GenerateRays(const Cameras& cameras, int64_t resolution) {
  CheckCameras(cameras);
  AVATAR_CHECK_INPUT(resolution >= 1) << "ray resolution must be >= 1, got " << resolution;
  const int64_t b = cameras.batch();
  const auto opts = cameras.cam2world.options();
  const torch::Tensor centres = (torch::arange(resolution, opts) + 0.5) / static_cast<double>(resolution);
  // Row-major pixel order: v follows the row, u the column.
  const torch::Tensor v = centres.view({resolution, 1}).expand({resolution, resolution}).reshape({1, -1});
  const torch::Tensor u = centres.view({1, resolution}).expand({resolution, resolution}).reshape({1, -1});
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
  rays.origins = cameras.cam2world.narrow(1, 0, 3).select(2, 3).unsqueeze(1).expand({b, resolution * resolution, 3});
  return rays;
}

}  // namespace avatar::render
