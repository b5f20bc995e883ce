#include "core/morphable/camera_label.h"

#include <cmath>

#include "core/util/error.h"

namespace avatar::morphable {

CameraLabel FrontalLabel() { return LabelFromTensor(render::LabelsFromCameras(render::FrontalCameras(1))); }

CameraLabel LabelFromPose(const cv::Matx33d& world_to_cam, const cv::Vec3d& centre) {
  CameraLabel label{};
  const cv::Matx33d r = world_to_cam.t();  // cam2world rotation
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) label[i * 4 + j] = static_cast<float>(r(i, j));
    label[i * 4 + 3] = static_cast<float>(centre[i]);
  }
  label[15] = 1.0f;
  const torch::Tensor k = render::DefaultIntrinsics(torch::kFloat32).reshape({9});
  for (int i = 0; i < 9; ++i) label[16 + i] = k[i].item<float>();
  return label;
}

torch::Tensor LabelTensor(const CameraLabel& label) {
  return torch::from_blob(const_cast<float*>(label.data()), {render::kCameraLabelSize}, torch::kFloat32).clone();
}

CameraLabel LabelFromTensor(const torch::Tensor& label) {
  AVATAR_CHECK_INPUT(label.defined() && label.numel() == render::kCameraLabelSize &&
                     (label.dim() == 1 || (label.dim() == 2 && label.size(0) == 1)))
      << "a camera label must be [25] or [1,25], got " << label.sizes();
  const torch::Tensor l = label.reshape({render::kCameraLabelSize}).to(torch::kCPU, torch::kFloat32).contiguous();
  CameraLabel out{};
  std::copy(l.data_ptr<float>(), l.data_ptr<float>() + render::kCameraLabelSize, out.begin());
  return out;
}

PinholeCamera PinholeCamera::FromLabel(const CameraLabel& label) {
  for (float v : label) AVATAR_CHECK_INPUT(std::isfinite(v)) << "camera label has non-finite values";
  PinholeCamera cam;
  cv::Matx33d r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r(i, j) = label[i * 4 + j];
    cam.centre[i] = label[i * 4 + 3];
  }
  const cv::Matx33d should_be_eye = r.t() * r;
  AVATAR_CHECK_INPUT(cv::norm(should_be_eye - cv::Matx33d::eye(), cv::NORM_INF) < 1e-3)
      << "camera label: the cam2world rotation is not orthonormal";
  AVATAR_CHECK_INPUT(std::abs(label[12]) + std::abs(label[13]) + std::abs(label[14]) < 1e-4 &&
                     std::abs(label[15] - 1.0f) < 1e-4)
      << "camera label: the last cam2world row must be (0,0,0,1)";
  cam.world_to_cam = r.t();
  for (int i = 0; i < 9; ++i) cam.k_normalised(i / 3, i % 3) = label[16 + i];
  AVATAR_CHECK_INPUT(cam.k_normalised(0, 0) > 0 && cam.k_normalised(1, 1) > 0 &&
                     std::abs(cam.k_normalised(2, 2) - 1.0) < 1e-4)
      << "camera label: invalid intrinsics";
  return cam;
}

cv::Vec3d PinholeCamera::ToCamera(const cv::Vec3d& world) const { return world_to_cam * (world - centre); }

cv::Point2d PinholeCamera::ToPixel(const cv::Vec3d& p, cv::Size size) const {
  const double xn = p[0] / p[2];
  const double yn = p[1] / p[2];
  const double u = k_normalised(0, 0) * xn + k_normalised(0, 1) * yn + k_normalised(0, 2);
  const double v = k_normalised(1, 1) * yn + k_normalised(1, 2);
  return {u * size.width, v * size.height};
}

}  // namespace avatar::morphable
