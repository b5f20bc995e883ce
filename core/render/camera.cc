#include "core/render/camera.h"

#include <cmath>

#include "core/util/error.h"

namespace avatar::render {

namespace {

torch::Tensor Normalize(const torch::Tensor& v) { return v / v.norm(2, -1, true); }

}  // namespace

torch::Tensor DefaultIntrinsics(const torch::TensorOptions& options) {
  return torch::tensor({kFocal, 0.0, kPrincipalPoint, 0.0, kFocal, kPrincipalPoint, 0.0, 0.0, 1.0},
                       torch::TensorOptions().dtype(torch::kFloat64))
      .view({3, 3})
      .to(options.device(), options.dtype().toScalarType());
}

torch::Tensor FrontalCam2World(const torch::TensorOptions& options) {
  std::vector<double> values(kFrontalCam2World.begin(), kFrontalCam2World.end());
  return torch::tensor(values, torch::TensorOptions().dtype(torch::kFloat64))
      .view({4, 4})
      .to(options.device(), options.dtype().toScalarType());
}

Cameras FrontalCameras(int64_t batch, const torch::TensorOptions& options) {
  AVATAR_CHECK_INPUT(batch >= 1) << "camera batch must be >= 1, got " << batch;
  Cameras cameras;
  cameras.cam2world = FrontalCam2World(options).unsqueeze(0).repeat({batch, 1, 1});
  cameras.intrinsics = DefaultIntrinsics(options).unsqueeze(0).repeat({batch, 1, 1});
  return cameras;
}

void CheckCameras(const Cameras& cameras) {
  AVATAR_CHECK_INPUT(cameras.cam2world.defined() && cameras.intrinsics.defined()) << "cameras are not set";
  AVATAR_CHECK_INPUT(cameras.cam2world.dim() == 3 && cameras.cam2world.size(1) == 4 && cameras.cam2world.size(2) == 4)
      << "cam2world must be [B,4,4], got " << cameras.cam2world.sizes();
  AVATAR_CHECK_INPUT(cameras.intrinsics.dim() == 3 && cameras.intrinsics.size(1) == 3 &&
                     cameras.intrinsics.size(2) == 3)
      << "intrinsics must be [B,3,3], got " << cameras.intrinsics.sizes();
  AVATAR_CHECK_INPUT(cameras.cam2world.size(0) == cameras.intrinsics.size(0) && cameras.cam2world.size(0) >= 1)
      << "cam2world and intrinsics batch sizes differ: " << cameras.cam2world.size(0) << " vs "
      << cameras.intrinsics.size(0);
  AVATAR_CHECK_INPUT(torch::isFloatingType(cameras.cam2world.scalar_type()) &&
                     cameras.cam2world.scalar_type() == cameras.intrinsics.scalar_type())
      << "cameras must share one floating dtype";
}

torch::Tensor LabelsFromCameras(const Cameras& cameras) {
  CheckCameras(cameras);
  const int64_t b = cameras.batch();
  return torch::cat({cameras.cam2world.reshape({b, 16}), cameras.intrinsics.reshape({b, 9})}, 1);
}

Cameras CamerasFromLabels(const torch::Tensor& labels) {
  AVATAR_CHECK_INPUT(labels.defined() && torch::isFloatingType(labels.scalar_type()))
      << "camera labels must be a floating tensor";
  const torch::Tensor l = labels.dim() == 1 ? labels.unsqueeze(0) : labels;
  AVATAR_CHECK_INPUT(l.dim() == 2 && l.size(1) == kCameraLabelSize && l.size(0) >= 1)
      << "camera labels must be [B,25] or [25], got " << labels.sizes();
  const int64_t b = l.size(0);
  Cameras cameras;
  cameras.cam2world = l.narrow(1, 0, 16).reshape({b, 4, 4});
  cameras.intrinsics = l.narrow(1, 16, 9).reshape({b, 3, 3});
  const auto opts = l.options();
  const torch::Tensor last_row = torch::tensor({0.0, 0.0, 0.0, 1.0}, torch::kFloat64).to(opts);
  const torch::Tensor k_row = torch::tensor({0.0, 0.0, 1.0}, torch::kFloat64).to(opts);
  const double tol = 1e-4;
  AVATAR_CHECK_INPUT((cameras.cam2world.select(1, 3) - last_row).abs().max().item<double>() <= tol)
      << "camera label: the last cam2world row must be (0,0,0,1)";
  AVATAR_CHECK_INPUT((cameras.intrinsics.select(1, 2) - k_row).abs().max().item<double>() <= tol)
      << "camera label: the last intrinsics row must be (0,0,1)";
  return cameras;
}

torch::Tensor LookAtCam2World(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& roll) {
  AVATAR_CHECK_INPUT(eye.dim() == 2 && eye.size(1) == 3 && target.sizes() == eye.sizes())
      << "look-at expects eye and target [B,3], got " << eye.sizes() << " and " << target.sizes();
  AVATAR_CHECK_INPUT(roll.dim() == 1 && roll.size(0) == eye.size(0))
      << "look-at expects roll [B], got " << roll.sizes();
  const torch::Tensor view = target - eye;
  const torch::Tensor dist = view.norm(2, -1);
  AVATAR_CHECK_INPUT(dist.min().item<double>() > 1e-9) << "look-at: the camera centre equals the target";
  const torch::Tensor z = view / dist.unsqueeze(-1);
  const torch::Tensor up = torch::zeros_like(z);
  up.select(1, 1).fill_(1.0);
  // Right = forward x up points to the image right for an upright camera (frontal: +x).
  const torch::Tensor right = torch::cross(z, up, 1);
  AVATAR_CHECK_INPUT(right.norm(2, -1).min().item<double>() > 1e-6)
      << "look-at: the viewing direction is vertical; keep |pitch| below 90 degrees";
  const torch::Tensor x0 = Normalize(right);
  const torch::Tensor y0 = torch::cross(z, x0, 1);  // camera down
  const torch::Tensor c = torch::cos(roll).unsqueeze(-1);
  const torch::Tensor s = torch::sin(roll).unsqueeze(-1);
  const torch::Tensor x = c * x0 + s * y0;
  const torch::Tensor y = -s * x0 + c * y0;
  const int64_t b = eye.size(0);
  torch::Tensor m = torch::zeros({b, 4, 4}, eye.options());
  m.narrow(1, 0, 3).select(2, 0).copy_(x);
  m.narrow(1, 0, 3).select(2, 1).copy_(y);
  m.narrow(1, 0, 3).select(2, 2).copy_(z);
  m.narrow(1, 0, 3).select(2, 3).copy_(eye);
  m.select(1, 3).select(1, 3).fill_(1.0);
  return m;
}

torch::Tensor OrbitCam2World(const ViewPose& pose, const torch::TensorOptions& options) {
  // Built in double, so that the zero pose reproduces the frontal constant exactly.
  const std::array<double, 16> m = ViewCam2World(pose, kFrontalCam2World);
  std::vector<double> values(m.begin(), m.end());
  return torch::tensor(values, torch::TensorOptions().dtype(torch::kFloat64))
      .view({4, 4})
      .to(options.device(), options.dtype().toScalarType());
}

torch::Tensor ProjectPoints(const torch::Tensor& points, const Cameras& cameras) {
  CheckCameras(cameras);
  AVATAR_CHECK_INPUT(points.dim() == 3 && points.size(2) == 3 && points.size(0) == cameras.batch())
      << "points must be [B,P,3] with B = " << cameras.batch() << ", got " << points.sizes();
  const torch::Tensor rot = cameras.cam2world.narrow(1, 0, 3).narrow(2, 0, 3);  // [B,3,3]
  const torch::Tensor centre = cameras.cam2world.narrow(1, 0, 3).select(2, 3);  // [B,3]
  // p_cam = R^T (p - c), as row vectors: (p - c) R.
  const torch::Tensor cam = torch::bmm(points - centre.unsqueeze(1), rot);  // [B,P,3]
  const torch::Tensor z = cam.select(2, 2);
  const torch::Tensor xn = cam.select(2, 0) / z;
  const torch::Tensor yn = cam.select(2, 1) / z;
  const auto& k = cameras.intrinsics;
  const auto kk = [&](int r, int c) { return k.select(1, r).select(1, c).unsqueeze(1); };  // [B,1]
  const torch::Tensor u = kk(0, 0) * xn + kk(0, 1) * yn + kk(0, 2);
  const torch::Tensor v = kk(1, 1) * yn + kk(1, 2);
  return torch::stack({u, v, z}, 2);
}

}  // namespace avatar::render
