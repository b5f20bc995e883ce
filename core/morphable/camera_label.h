#pragma once
// The 25-float EG3D camera label (row-major cam2world 4x4 + row-major normalised intrinsics 3x3)
// as a plain array, with conversions to the torch cameras of core/render (same convention).

#include <array>

#include <torch/torch.h>
#include <opencv2/core.hpp>

#include "core/render/camera.h"

namespace avatar::morphable {

using CameraLabel = std::array<float, render::kCameraLabelSize>;

// render::FrontalCameras(1) as a label (C_front).
CameraLabel FrontalLabel();
// Label of a camera with world->camera rotation `world_to_cam` (OpenCV camera axes) and centre
// `centre` (world), with the published intrinsics.
CameraLabel LabelFromPose(const cv::Matx33d& world_to_cam, const cv::Vec3d& centre);
// [25] float32 tensor.
torch::Tensor LabelTensor(const CameraLabel& label);
// Inverse of LabelTensor; accepts [25] or [1,25]. Throws InvalidInput on bad shapes.
CameraLabel LabelFromTensor(const torch::Tensor& label);

// Pinhole camera decoded from a label for CPU projection.
struct PinholeCamera {
  cv::Matx33d world_to_cam;  // R^T of cam2world
  cv::Vec3d centre;          // camera centre, world
  cv::Matx33d k_normalised;  // intrinsics normalised by the image size

  // Throws InvalidInput for a label that is not a rigid camera with a valid K.
  static PinholeCamera FromLabel(const CameraLabel& label);
  // World point -> camera coordinates (OpenCV axes: x right, y down, z forward).
  cv::Vec3d ToCamera(const cv::Vec3d& world) const;
  // Camera point -> pixel position (x, y) in an image of `size` (pixel i covers [i, i+1)).
  cv::Point2d ToPixel(const cv::Vec3d& cam, cv::Size size) const;
};

}  // namespace avatar::morphable
