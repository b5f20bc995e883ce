#pragma once
// Cameras in GOHA's (EG3D's) conventions.
//
// World: y up; the head sits in the box [-0.5,0.5]^3 around the origin, facing +z.
// Camera: OpenCV axes (x right, y down, z forward); cam2world is a 4x4 matrix whose
// columns 0..2 are those axes in world coordinates and column 3 the camera centre.
// Intrinsics are normalised by the image size: pixel (u,v) in [0,1]^2 with
// u = fx * x/z + skew * y/z + cx, v = fy * y/z + cy.
// Label: the 25 floats of a dataset.json entry = row-major cam2world (16) + row-major K (9).
//
// Every function works on any device and floating dtype, and keeps the input's.

#include <array>

#include <torch/torch.h>

#include "core/render/view_pose.h"

namespace avatar::render {

// Floats in one camera label.
inline constexpr int64_t kCameraLabelSize = 25;

// A batch of cameras.
struct Cameras {
  torch::Tensor cam2world;   // [B,4,4]
  torch::Tensor intrinsics;  // [B,3,3] normalised by image size

  int64_t batch() const { return cam2world.size(0); }
};

// The published intrinsics (fx = fy = kFocal, cx = cy = kPrincipalPoint, no skew). [3,3]
torch::Tensor DefaultIntrinsics(const torch::TensorOptions& options = torch::kFloat32);
// kFrontalCam2World as a tensor. [4,4]
torch::Tensor FrontalCam2World(const torch::TensorOptions& options = torch::kFloat32);
// `batch` copies of the frontal camera with the default intrinsics.
Cameras FrontalCameras(int64_t batch = 1, const torch::TensorOptions& options = torch::kFloat32);

// cam2world [B,4,4] + intrinsics [B,3,3] -> labels [B,25]. Throws InvalidInput on bad shapes.
torch::Tensor LabelsFromCameras(const Cameras& cameras);
// labels [B,25] or [25] -> cameras (B = 1 for a single label). Throws InvalidInput on bad shapes
// or a label whose last cam2world row is not (0,0,0,1) or whose K[2] row is not (0,0,1).
Cameras CamerasFromLabels(const torch::Tensor& labels);

// Checks shapes and dtypes of a camera batch; throws InvalidInput naming the problem.
void CheckCameras(const Cameras& cameras);

// Look-at cam2world: eye [B,3], target [B,3], roll [B] radians (rotation about the viewing
// axis; positive roll turns the camera's right axis towards its down axis), world up +y.
// Returns [B,4,4]. Throws InvalidInput when eye == target or the view is vertical.
torch::Tensor LookAtCam2World(const torch::Tensor& eye, const torch::Tensor& target, const torch::Tensor& roll);

// The cam2world [4,4] of a pose about the frontal camera: ViewCam2World(pose, kFrontalCam2World)
// (view_pose.h), a camera on a sphere of radius kCameraRadius / zoom around the origin, looking at
// it. OrbitCam2World({}) equals FrontalCam2World(). Throws InvalidOptions for a bad pose.
torch::Tensor OrbitCam2World(const ViewPose& pose, const torch::TensorOptions& options = torch::kFloat32);

// Projects world points [B,P,3] into each camera: returns [B,P,3] = (u, v, z) with (u,v) the
// normalised image position and z the depth along the camera's optical axis.
torch::Tensor ProjectPoints(const torch::Tensor& points, const Cameras& cameras);

}  // namespace avatar::render
